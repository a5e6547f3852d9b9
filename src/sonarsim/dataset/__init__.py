"""Datasets: scenarios (trajectories, scene variation, per-frame seeds) rendered frame by frame.

:func:`load_scenario` reads a scenario file; :meth:`Scenario.frame` gives frame ``k`` as a
:class:`FrameSpec`, a pure function of the scenario and ``k``. :func:`frames` renders them in
memory (for training loops); :func:`generate` writes them to a resumable dataset folder
(NPZ per frame, manifest, COCO boxes, ROS 2 bag); :func:`write_instrument_dataset` writes a
scene's other instruments (side-scan, scanning, single-beam, multibeam) in chunks of pings.
"""

from .frames import Frame, frames
from .instruments import write_instrument_dataset
from .scenario import FrameSpec, Scenario, load_scenario
from .writer import DatasetSummary, generate

__all__ = ["DatasetSummary", "Frame", "FrameSpec", "Scenario", "frames", "generate", "load_scenario",
           "write_instrument_dataset"]
