"""Datasets: scenarios (trajectories, scene variation, per-frame seeds) rendered frame by frame.

:func:`load_scenario` reads a scenario file; :meth:`Scenario.frame` gives frame ``k`` as a
:class:`FrameSpec`, a pure function of the scenario and ``k``.
"""

from .scenario import FrameSpec, Scenario, load_scenario

__all__ = ["FrameSpec", "Scenario", "load_scenario"]
