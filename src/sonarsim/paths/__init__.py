"""Acoustic paths beyond the single bounce: the flat ground's double and triple echoes
(paper Section IV); :mod:`~sonarsim.paths.algorithm2` holds the fast method and the paper's
literal Algorithm 2."""
