"""The sensor stage: from the renderer's noise-free image to what a device outputs.

:mod:`~sonarsim.sensor.acoustics` (absorption, the sonar equation's range terms, TVG),
:mod:`~sonarsim.sensor.patterns` (beam patterns of line arrays), :mod:`~sonarsim.sensor.pulse`
(range point-spread), :mod:`~sonarsim.sensor.speckle` (coherent speckle and noise fields),
:mod:`~sonarsim.sensor.output` (compression, quantisation, expected output),
:mod:`~sonarsim.sensor.channels` (per-beam and per-row factors of the receive channels: the
across-fan gain and stripes, the bang's pattern across beams and its ringing, noise common to a
row's beams) and
:mod:`~sonarsim.sensor.model` (:class:`SensorModel`, which chains them per frame). Configured
by the scene's ``sensor:`` section (:mod:`sonarsim.config.sensor`).
"""

from .model import SensorModel

__all__ = ["SensorModel"]
