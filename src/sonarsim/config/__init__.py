"""Configuration: the frozen specs of the sonar and the scene, their YAML/JSON I/O, presets.

:mod:`~sonarsim.config.sonar` (the intrinsics: beams, range window), :mod:`~sonarsim.config.scene`
(the sonar pose, objects, ground, render settings), :mod:`~sonarsim.config.materials` (backscatter
laws), :mod:`~sonarsim.config.loader` (documents to specs,
validated once at the edge), :mod:`~sonarsim.config.presets` (commercial sonars) and
:mod:`~sonarsim.config.instrument_presets` (side-scan, multibeam, scanning and single-beam devices).
"""
