"""Configuration: the frozen specs of the sonar and the scene, their YAML/JSON I/O, presets.

:mod:`~sonarsim.config.sonar` (beams, range window, pose), :mod:`~sonarsim.config.scene`
(objects, ground, render settings), :mod:`~sonarsim.config.loader` (documents to specs,
validated once at the edge) and :mod:`~sonarsim.config.presets` (commercial sonars).
"""
