"""Core geometry and physics shared by the pipeline: poses, ray fans, radiometry, memory.

:mod:`~sonarsim.core.transforms` (frames and poses), :mod:`~sonarsim.core.rays` (the ray fan of
a sonar), :mod:`~sonarsim.core.radiometry` (per-ray backscatter) and
:mod:`~sonarsim.core.memory` (allocator tuning for per-frame temporaries).
"""
