"""Acoustic paths beyond the single bounce, over any reflecting planes: the planes and chains
of them (:mod:`~sonarsim.paths.planes`) and the path engine's NumPy twin
(:mod:`~sonarsim.paths.engine`). The oracles it is tested against are in
:mod:`sonarsim.reference`."""
