"""Core geometry and physics shared by the pipeline: poses, ray fans, radiometry, memory.

:mod:`~sonarsim.core.transforms` (frames and poses), :mod:`~sonarsim.core.rays` (the ray fan of
a sonar), :mod:`~sonarsim.core.radiometry` (per-ray backscatter) and
:mod:`~sonarsim.core.memory` (allocator tuning for per-frame temporaries); with the process-level
helpers :mod:`~sonarsim.core.interrupts` (Ctrl-C held back) and :mod:`~sonarsim.core.console`
(``sonarsim: ...`` messages and one-line warnings).

The bottom layer: it imports nothing of the package but :mod:`sonarsim.errors`
(tests/core/test_core_imports_nothing.py).
"""
