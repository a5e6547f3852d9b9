"""Fit the sonar pose to a real image by rendering and comparing (the paper's calibration).

Raw intensities of a real image depend on gain, speckle and the transducer; the places where
the echo starts and stops (the onset of the floor, the front of an object, the edge of a
shadow) depend on the pose. Two comparison domains:

* ``edges`` (the paper's authors calibrated this way): both images become edge maps --
  smoothed log-intensity, differentiated along range -- and the cost is one minus their
  normalised correlation, coarse to fine over decreasing smoothing. General scenes.
* ``band``: per beam, the near and far edges of the floor band (the steepest rise of the
  echo and the steepest fall after it); the cost is the RMS difference of those curves, in
  metres. For calibrating height and tilt against a floor: both edges are needed (the near
  edge alone lets height and tilt trade off), and they are far less sensitive to speckle and
  to the unmodelled brightness of the floor beyond the aperture than whole images are.

The real-time renderer makes each evaluation cheap; a derivative-free simplex search (scipy's
Nelder-Mead) does the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import ndimage, optimize

from ..errors import ConfigError, SonarsimError
from ..config.scene import Scene
from ..image.result import SonarImage
from ..renderer.simulator import Simulator
from ..core.transforms import Pose

PARAMETERS = ("x", "y", "z", "roll", "pitch", "yaw")
UNITS = {"x": "m", "y": "m", "z": "m", "roll": "deg", "pitch": "deg", "yaw": "deg"}
# Initial simplex steps: a few range bins of a typical tank window, a few degrees.
STEPS = {"x": 0.05, "y": 0.05, "z": 0.05, "roll": 2.0, "pitch": 2.0, "yaw": 2.0}
# Smoothing (range bins, beams) of the coarse-to-fine passes: wide first, to see far edges.
DEFAULT_SMOOTHING = ((8.0, 4.0), (4.0, 2.0), (2.0, 1.0))


def parse_free(text: str | Sequence[str], allow_none: bool = False) -> tuple[str, ...]:
    """``"z,pitch"`` or ``["z", "pitch"]`` -> ``("z", "pitch")``; unknown names are errors.

    ``allow_none``: an empty list is allowed (a calibration may fit no pose parameter).
    """
    names = [t.strip() for t in (text.split(",") if isinstance(text, str) else text) if t.strip()]
    if not names and not allow_none:
        raise ConfigError("free", f"name at least one pose parameter: {', '.join(PARAMETERS)}")
    for n in names:
        if n not in PARAMETERS:
            raise ConfigError("free", f"unknown pose parameter {n!r}; allowed: {', '.join(PARAMETERS)}")
    if len(set(names)) != len(names):
        raise ConfigError("free", f"a parameter is named twice in {names}")
    return tuple(names)


def pose_values(pose: Pose) -> dict[str, float]:
    """The six pose parameters (metres, degrees) of a pose."""
    (x, y, z), (roll, pitch, yaw) = pose.position_m, pose.rpy_deg
    return {"x": x, "y": y, "z": z, "roll": roll, "pitch": pitch, "yaw": yaw}


def pose_from_values(values: dict[str, float]) -> Pose:
    return Pose((values["x"], values["y"], values["z"]), (values["roll"], values["pitch"], values["yaw"]))


def edge_map(polar: np.ndarray, smoothing: tuple[float, float]) -> np.ndarray:
    """Normalised range-edge map of a polar image.

    Parameters
    ----------
    polar : (n_range_bins, n_beams) float array
        Intensities (any scale; >= 0).
    smoothing : (float, float)
        Gaussian sigma along range (bins) and azimuth (beams).

    Returns
    -------
    (n_range_bins, n_beams) float64 ndarray with zero mean and unit norm (all zeros for a
    featureless image): the magnitude of the range derivative of the smoothed log-intensity.
    """
    img = np.asarray(polar, dtype=float)
    scale = np.percentile(img[img > 0], 99) if np.any(img > 0) else 1.0
    # log1p of the image scaled to its own level: contrast, not absolute gain, matters.
    logged = np.log1p(np.clip(img, 0, None) / (0.05 * scale))
    smooth = ndimage.gaussian_filter(logged, smoothing, mode="nearest")
    edges = np.abs(np.gradient(smooth, axis=0))
    edges -= edges.mean()
    norm = np.linalg.norm(edges)
    return edges / norm if norm > 0 else edges


def edge_cost(simulated: np.ndarray, real_edges: np.ndarray, smoothing: tuple[float, float]) -> float:
    """1 - correlation of the edge maps, in [0, 2]; 0 is a perfect match."""
    return 1.0 - float(np.sum(edge_map(simulated, smoothing) * real_edges))


# Smoothing (range bins, beams) of the band-edge detector and the width (beams) of the median
# filter across beams: speckle makes single-beam edges of a real image jump by centimetres.
BAND_SMOOTHING = (12.0, 8.0)
BAND_MEDIAN_BEAMS = 15


def floor_band_m(
    image: SonarImage, smoothing: tuple[float, float] = BAND_SMOOTHING, median_beams: int = BAND_MEDIAN_BEAMS
) -> tuple[np.ndarray, np.ndarray]:
    """Per beam, the near and far edges of a floor band: the steepest rise of the echo, and
    the steepest fall after it.

    Edges are taken on the smoothed log-intensity (``smoothing``: Gaussian sigmas in range bins
    and beams, against speckle), like :func:`edge_map`, so that they do not depend on gain or
    on how the brightness varies inside the band; then a median over ``median_beams``
    neighbouring beams removes outliers. On a flat floor the near edge is where the
    lowest ray of the elevation aperture meets it, the far edge the highest ray (when inside
    the range window).

    Returns
    -------
    onset, end : (n_beams,) float64 ndarrays, metres; NaN for a beam without echo.
    """
    img = np.clip(np.asarray(image.polar, dtype=float), 0, None)
    scale = np.percentile(img[img > 0], 99) if np.any(img > 0) else 1.0
    smooth = ndimage.gaussian_filter(np.log1p(img / (0.05 * scale)), smoothing, mode="nearest")
    slope = np.gradient(smooth, axis=0)
    r = np.asarray(image.range_m)
    first = np.argmax(slope, axis=0)
    after = np.where(np.arange(len(r))[:, None] > first[None, :], slope, np.inf)
    last = np.argmin(after, axis=0)
    valid = (slope.max(axis=0) > 0) & np.isfinite(after.min(axis=0)) & (after.min(axis=0) < 0)
    onset = np.where(slope.max(axis=0) > 0, r[first], np.nan)
    end = np.where(valid, r[last], np.nan)
    if median_beams > 1:  # a median across neighbouring beams removes the speckle outliers
        onset = ndimage.median_filter(onset, median_beams, mode="nearest")
        end = ndimage.median_filter(end, median_beams, mode="nearest")
    return onset, end


def floor_onset_m(image: SonarImage, **kwargs) -> np.ndarray:
    """The near edge of the floor band in each beam, metres (see :func:`floor_band_m`)."""
    return floor_band_m(image, **kwargs)[0]


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_pose`.

    Attributes
    ----------
    pose : Pose
        The fitted sonar pose (world frame).
    scene : Scene
        The scene fitted, with ``pose`` as its ``sonar_pose`` (its sonar intrinsics unchanged).
    free : tuple of str
        The parameters that were fitted.
    domain : str
        The comparison domain (``edges`` or ``onset``).
    start, values : dict of str to float
        All six parameters before and after, metres and degrees.
    cost_start, cost : float
        The domain's cost at the start and at the fitted pose: 1 - edge correlation at the
        finest smoothing, or the RMS of the band-edge differences in metres.
    onset_rms_m : float
        RMS over beams of the difference between the real and the fitted floor onset ranges,
        metres (NaN where no beam shows a floor in both).
    renders : int
        Number of images rendered.
    image : SonarImage
        The render at the fitted pose (its ``pose``), in the real image's geometry (its ``sonar``:
        the real image's beams and range window, the scene's elevation aperture).
    """

    pose: Pose
    free: tuple[str, ...]
    domain: str
    start: dict
    values: dict
    cost_start: float
    cost: float
    onset_rms_m: float
    renders: int
    image: SonarImage
    scene: Scene


DOMAINS = ("edges", "band")


def check_overlap(real: SonarImage, scene: Scene) -> None:
    """Refuse a recording whose window the scene's sonar hardly covers (as ``compare`` does).

    Fitting and calibration render on the recording's grid; a recording of another range window
    or fan is another sonar setting (or another scene), and nothing there can be fitted.

    Raises
    ------
    SonarsimError
        Less than :data:`~sonarsim.analysis.comparison.MIN_OVERLAP` of the recording's area is shared.
    """
    from .comparison import MIN_OVERLAP, _overlap_fraction

    overlap = _overlap_fraction(real.sonar.grid, scene.sonar.grid)
    if overlap < MIN_OVERLAP:
        g, h = real.sonar.grid, scene.sonar.grid
        raise SonarsimError(
            f"the recording covers {g.range_min_m:.3g}-{g.range_max_m:.3g} m over {g.right_edge_deg:.3g} to "
            f"{g.left_edge_deg:.3g} deg, the scene's sonar {h.range_min_m:.3g}-{h.range_max_m:.3g} m over "
            f"{h.right_edge_deg:.3g} to {h.left_edge_deg:.3g} deg: they share {100 * overlap:.0f} % of the "
            f"recording's area (at least {100 * MIN_OVERLAP:.0f} % is needed); give the scene the recording's "
            "sonar settings")


def fit_pose(
    real: SonarImage,
    scene: Scene,
    free: Sequence[str] = ("z", "pitch"),
    domain: str = "edges",
    smoothing: Sequence[tuple[float, float]] = DEFAULT_SMOOTHING,
    max_renders: int = 600,
    simulator: Simulator | None = None,
) -> FitResult:
    """Find the sonar pose parameters that make the rendered image match a real one.

    Parameters
    ----------
    real : SonarImage
        The real (or reference) image; its beam angles, range window and bins are used for the
        renders.
    scene : Scene
        The scene; its sonar pose (``scene.sonar_pose``) is the starting point, its elevation
        aperture is used.
    free : sequence of {'x', 'y', 'z', 'roll', 'pitch', 'yaw'}
        Parameters to fit; the others keep the scene's values.
    domain : {'edges', 'band'}
        What is compared (see the module docstring).
    smoothing : sequence of (float, float)
        Gaussian sigmas (range bins, beams) of the coarse-to-fine passes (``edges``).
    max_renders : int
        Budget of renders over all passes.
    simulator : Simulator, optional
        Reused if given (it must hold ``scene``).
    """
    free = parse_free(free)
    if domain not in DOMAINS:
        raise ConfigError("domain", f"unknown domain {domain!r}; allowed: {', '.join(DOMAINS)}")
    check_overlap(real, scene)
    sim = simulator if simulator is not None else Simulator(scene)
    # The intrinsics of every render (fixed); only the pose varies.
    geometry = replace(real.sonar, elevation_fov_deg=scene.sonar.elevation_fov_deg)
    start = pose_values(scene.sonar_pose)
    renders = 0
    real_onset, real_end = floor_band_m(real)

    def render_at(vec: np.ndarray) -> SonarImage:
        nonlocal renders
        renders += 1
        values = dict(start, **dict(zip(free, map(float, vec))))
        return sim.render(pose=pose_from_values(values), sonar=geometry, keep_rays=False)

    def onset_rms(image: SonarImage) -> float:
        d = floor_onset_m(image) - real_onset
        return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else 1e3

    def band_rms(image: SonarImage) -> float:
        onset, end = floor_band_m(image)
        d = np.concatenate([onset - real_onset, end - real_end])
        return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else 1e3

    def search(cost, x, budget):
        simplex = np.vstack([x] + [x + STEPS[n] * np.eye(len(free))[i] for i, n in enumerate(free)])
        return optimize.minimize(
            cost, x, method="Nelder-Mead",
            options={"initial_simplex": simplex, "maxfev": budget, "xatol": 1e-4, "fatol": 1e-7},
        ).x

    x0 = np.array([start[n] for n in free])
    if domain == "edges":
        x = x0
        for sigma in smoothing:
            target = edge_map(real.polar, sigma)
            x = search(lambda v, s=sigma, t=target: edge_cost(render_at(v).polar, t, s), x,
                       max(1, max_renders // len(smoothing)))
        finest = tuple(smoothing[-1])
        target = edge_map(real.polar, finest)

        def final_cost(image):
            return edge_cost(image.polar, target, finest)
    else:
        x = search(lambda v: band_rms(render_at(v)), x0, max_renders)
        final_cost = band_rms
    cost_start = final_cost(render_at(x0))
    fitted = render_at(x)
    values = dict(start, **dict(zip(free, map(float, x))))
    pose = pose_from_values(values)
    if not np.any(fitted.polar > 0) or not np.isfinite(final_cost(fitted)):
        raise SonarsimError("the fit found no pose at which the scene echoes inside the recording's window "
                            f"(started at {', '.join(f'{k} {start[k]:.4g}' for k in free)}): nothing to compare; "
                            "check the scene, its sonar settings and the starting pose")
    return FitResult(
        pose=pose, scene=scene.with_pose(pose), free=free, domain=domain, start=start, values=values,
        cost_start=cost_start, cost=final_cost(fitted), onset_rms_m=onset_rms(fitted), renders=renders,
        image=fitted,
    )
