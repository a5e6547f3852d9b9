"""The forward-looking sonar as an instrument: each ping one polar frame (today's renderer)."""

from __future__ import annotations

import numpy as np

from ..config.instruments import FlsSpec
from . import channel_pose, renders

__all__ = ["render_fls"]


@renders("fls")
def render_fls(sim, spec: FlsSpec, poses, times_s: np.ndarray, first_ping: int, speckle, labels) -> list:
    """One :class:`~sonarsim.image.result.SonarImage` per ping, exactly what
    :meth:`Simulator.render` gives at the mounted pose (the frame index ``first_ping + k``)."""
    channel = spec.channels()[0]
    out = []
    for k, v in enumerate(poses):
        sim.at_time(float(times_s[k]))  # objects on tracks, where they are at the ping
        out.append(sim.render(pose=channel_pose(v, channel), sonar=channel.sonar, frame=first_ping + k,
                              speckle=speckle, labels=labels if labels else False))
    return out
