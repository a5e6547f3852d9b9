"""The path buffer's contract: what the search hands to image formation, for one frame.

The search (:meth:`sonarsim.Simulator.trace`: the scene's surfaces, a fan of rays, a pose ->
the frame's paths) and image formation (:meth:`sonarsim.Simulator.form`: paths -> a film's
image, components and labels) meet here and nowhere else. Every instrument
(:mod:`sonarsim.instruments`), the differentiable engine (:mod:`sonarsim.diff`) and calibration
call the two steps; none reaches into how a frame's paths were found. ``docs/path-buffer.md``
describes the arrays inside (the receive legs, the transmit options, the paths).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..config.sonar import SonarConfig
from ..core.rays import RayFan
from ..core.transforms import Pose
from .engine import SonarView
from .planes import ChainTable

__all__ = ["FramePaths"]


@dataclass(frozen=True)
class FramePaths:
    """One frame's paths, as the search found them.

    Attributes
    ----------
    sonar : SonarConfig
        The image's grid (range bins x beams) and intrinsics, as asked for.
    traced : SonarConfig
        The sonar whose rays were cast: ``sonar`` widened to a sensor's elevation span.
    pose : Pose
        The sonar's pose in the world frame (sonar-to-world).
    view : SonarView
        The pose and fan of the frame, its rays rotated into the world.
    stack : (rows, n_range_bins, n_beams) float32 ndarray
        The image stack: one row per path order (``renderer.components.stack_rows``).
    legs : FrameLegs or list of Leg
        The receive legs, generation by generation (``docs/path-buffer.md``, "The receive legs").
    sets : list of PathSet, a callable returning them, or None
        The paths (None for ``method: paper``, which forms images, not paths).
    table : ChainTable or None
        The frame's chains of planes and mirrors, canonically numbered.
    total : (n_range_bins, n_beams) float32 ndarray or None
        The rows of ``render.bounces`` already summed by the engine, else None.
    formed : object or None
        Label maps the compiled engine formed in its own pass (``labels`` asked of the trace).
    label_spec : LabelSpec or None
        What the labels are of (asked of the trace), else None.
    labels : bool or str
        The labels asked of the trace (``Simulator.render``'s ``labels``).
    active : (P,) bool ndarray
        The planes the sonar faces.
    n_generations : int
        Receive-leg generations traced.
    reach_m : float
        The longest receive leg followed, metres.
    timing : dict of str to float
        ``setup`` and ``render`` seconds of the trace (``t0``: when it began, ``perf_counter``).
    poses : tuple of Pose or None
        A frame of several poses (``Simulator.trace_poses``): pose ``p``'s rays are the fan's
        ``p``-th share along its beams, its image the grid's ``p``-th share of the beams; ``pose``
        and ``view`` are the first pose's. None: one pose.
    """

    sonar: SonarConfig
    traced: SonarConfig
    pose: Pose
    view: SonarView
    stack: np.ndarray
    legs: Any
    sets: list | Callable[[], list] | None
    table: ChainTable | None
    total: np.ndarray | None
    formed: Any = None
    label_spec: Any = None
    labels: bool | str = False
    active: np.ndarray | None = None
    n_generations: int = 1
    reach_m: float = 0.0
    timing: dict | None = None
    poses: tuple[Pose, ...] | None = None

    @property
    def fan(self) -> RayFan:
        """The fan of rays cast, in the sonar's frame."""
        return self.view.fan

    @property
    def primary(self):
        """The first receive leg (generation 0: each ray's first surface)."""
        return self.legs[0]

    def world_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Each ray's origin and direction in the world: ``(origins, directions)``, both shaped
        ``fan.shape + (3,)`` (float64), each pose's rays from its own pose."""
        fan = self.fan
        if self.poses is None:
            return np.broadcast_to(self.view.origin, fan.shape + (3,)), self.view.directions
        n = len(self.poses)
        d = fan.directions.reshape((n, -1, 3))
        rot = np.array([p.rotation for p in self.poses])
        org = np.array([p.translation for p in self.poses], dtype=float)
        out = np.einsum("pij,pkj->pki", rot, d)
        return (np.broadcast_to(org[:, None, :], out.shape).reshape(fan.shape + (3,)),
                out.reshape(fan.shape + (3,)))

    def first_hits(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each ray's first surface: ``(distance_m, surface_id, intensity)``, each shaped like
        the fan ``(n_beams, n_azimuth_samples, n_elevation_samples)``; ``distance_m`` is
        ``inf`` and ``surface_id`` -1 where a ray meets nothing (surface ids: plane ``p`` is
        ``p``, object ``k`` is ``P + k``)."""
        leg, shape = self.primary, self.fan.shape
        sid = np.asarray(leg.sid).reshape(shape)
        return (np.asarray(leg.distance).reshape(shape), sid,
                np.where(sid >= 0, np.asarray(leg.intensity).reshape(shape), 0.0))
