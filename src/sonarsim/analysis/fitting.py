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

``auto`` (the default) chooses between them from the scene and the recording
(:func:`choose_domain`): ``band`` where the scene's echo is one floor band, ``edges`` otherwise.

The real-time renderer makes each evaluation cheap; a derivative-free simplex search (scipy's
Nelder-Mead) does the rest. A simplex ends somewhere whether or not that means anything:
:func:`fit_problems` lists the signs that it does not (an echo that does not line up with the
recording's, band edges a window's tenth apart, a search that found no way downhill, a
parameter that ran away), and ``sonarsim fit`` exits with status 3 on any of them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
from scipy import ndimage, optimize

from ..errors import ConfigError, SonarsimError
from ..config.scene import Scene
from ..config.sonar import SonarConfig
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


# What makes a fit meaningless (see :func:`fit_problems`). Smoothing of the domain-neutral check:
# the widest pass of the edges domain, where a floor band or an object front is one broad edge
# and speckle has averaged out.
CHECK_SMOOTHING = DEFAULT_SMOOTHING[0]
# Least correlation of the edge maps (at CHECK_SMOOTHING) between the recording and the render
# at the fitted pose. Measured: 0.45 on the real Oculus floor ping at its fitted pose, 0.99 on
# the noisy demo scene at its true pose, 0.73 at a start 8 cm and 3 deg off; -0.17 and 0.11 at
# poses where the render's echo lies elsewhere than the recording's (1.5 m and 60 deg; 2.5 m
# and 60 deg).
MIN_EDGE_CORRELATION = 0.2
# Largest RMS band-edge difference (``band`` domain), as a fraction of the recording's range
# span: 0.064 m (3 %) on the real floor ping; beyond a tenth of the window the two bands are
# different echoes, not one echo slightly displaced.
MAX_BAND_RMS_FRACTION = 0.1
# A cost this low (either domain) is a perfect match: a search that stays put there is done.
PERFECT_COST = 1e-6
# A parameter that moves farther than the recording's far range (metres) or than this (degrees)
# from the start has run away along a flat or misleading cost, not converged.
MAX_ANGLE_MOVE_DEG = 90.0
# ``auto`` chooses ``band`` when the objects carry at most this share of the single-bounce
# echo at the start and the band is found in at least MIN_BAND_BEAMS of the beams.
MAX_OBJECT_SHARE = 0.05
MIN_BAND_BEAMS = 0.5

# Sentinel cost of a band comparison without a beam where both images show a band: finite, so
# that the simplex can step away from it; reported as a problem, never as a residual.
NO_BAND_COST = 1e3


class FitError(SonarsimError):
    """The fit ran but found no meaningful pose (the CLI's exit status 3)."""


@dataclass(frozen=True)
class FitProgress:
    """What :func:`fit_pose` reports to its ``progress`` callback after each render.

    Attributes
    ----------
    renders : int
        Images rendered so far.
    budget : int
        The render budget (``max_renders``).
    stage : str
        The pass running: ``band``, or ``edges 2/3`` (pass and number of passes).
    best_cost : float
        The lowest cost of the current pass so far (its units: see :attr:`FitResult.cost`).
    elapsed_s : float
        Seconds since the fit started.
    """

    renders: int
    budget: int
    stage: str
    best_cost: float
    elapsed_s: float


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_pose`.

    Attributes
    ----------
    pose : Pose
        The fitted sonar pose (world frame).
    scene : Scene
        The scene fitted, with ``pose`` as its ``sonar_pose`` and the recording's intrinsics
        (:func:`recording_geometry`): it renders :attr:`image`, on the recording's grid.
    free : tuple of str
        The parameters that were fitted.
    domain : str
        The comparison domain used (``edges`` or ``band``; ``auto`` resolved).
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
        the real image's beams and range window, the scene's elevation aperture;
        :func:`recording_geometry`).
    domain_reason : str
        Why the domain was used (the rule of :func:`choose_domain`, or "asked for").
    edge_correlation : float
        Correlation of the edge maps of the recording and of the fitted render at
        :data:`CHECK_SMOOTHING`: the domain-neutral check of :func:`fit_problems`.
    problems : tuple of str
        Why the fit is meaningless (:func:`fit_problems`); empty for a fit to be trusted.
    converged : bool
        The last search stopped on its tolerances, not on the render budget.
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
    domain_reason: str = ""
    edge_correlation: float = float("nan")
    problems: tuple[str, ...] = ()
    converged: bool = True

    @property
    def meaningful(self) -> bool:
        """No problem found (:attr:`problems` is empty)."""
        return not self.problems


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
        source = real.config.get("source") if isinstance(real.config, dict) else None
        raise SonarsimError(
            (f"{source}: " if source else "") + f"the recording covers {g.range_min_m:.3g}-{g.range_max_m:.3g} m over {g.right_edge_deg:.3g} to "
            f"{g.left_edge_deg:.3g} deg, the scene's sonar {h.range_min_m:.3g}-{h.range_max_m:.3g} m over "
            f"{h.right_edge_deg:.3g} to {h.left_edge_deg:.3g} deg: they share {100 * overlap:.0f} % of the "
            f"recording's area (at least {100 * MIN_OVERLAP:.0f} % is needed); give the scene the recording's "
            "sonar settings")


def recording_geometry(real: SonarImage, scene: Scene) -> SonarConfig:
    """The sonar intrinsics that fitting and calibration render with: the recording's.

    The recording's beams (its bearing table), range window and range bins, so that renders
    land on its grid pixel for pixel (nothing is resampled when they are compared), with what a
    recording does not say taken from the scene's sonar: the elevation aperture, and the
    frequency where the recording has none. ``sonarsim fit`` and ``sonarsim calibrate`` write
    these intrinsics into the scene files they make.

    Parameters
    ----------
    real : SonarImage
        The recording's frame (its ``sonar``).
    scene : Scene
        The scene behind it.

    Returns
    -------
    SonarConfig
    """
    sonar = replace(real.sonar, elevation_fov_deg=scene.sonar.elevation_fov_deg)
    if sonar.frequency_khz is None:
        sonar = replace(sonar, frequency_khz=scene.sonar.frequency_khz)
    return sonar


def _band_beams(image: SonarImage) -> float:
    """Fraction of the beams in which :func:`floor_band_m` finds both edges of a band."""
    onset, end = floor_band_m(image)
    return float(np.mean(np.isfinite(onset) & np.isfinite(end)))


def choose_domain(real: SonarImage, scene: Scene, start: SonarImage) -> tuple[str, str]:
    """The comparison domain for a scene and a recording (``fit --domain auto``), and why.

    ``band`` compares one band per beam, the direct echo of one floor, and nothing else: where
    that is what the scene shows, its near and far edges fix height and tilt, and it is blind to
    the speckle that the whole-image edges of ``edges`` follow off to a wrong pose (the real
    Oculus floor ping: a near-edge residual of 0.118 m with ``edges``, 0.068 m with ``band``).
    Where objects echo, or several planes do, their edges carry the pose and ``band`` would
    miss them or mistake one plane's band for another's. So ``band`` is chosen when all of these
    hold, ``edges`` otherwise:

    * the scene has exactly one reflecting plane (``ground`` or one entry of ``planes``);
    * at the start pose its objects carry at most :data:`MAX_OBJECT_SHARE` of the single-bounce
      echo inside the recording's window, and some of it if it has objects (objects out of
      view at the start may still be in the recording);
    * the recording, and the render at the start pose (where anything echoes), show both edges
      of a band in at least :data:`MIN_BAND_BEAMS` of their beams.

    Parameters
    ----------
    real : SonarImage
        The recording.
    scene : Scene
        The scene, at its starting pose.
    start : SonarImage
        The render of ``scene`` at its starting pose, on the recording's grid (with its
        ``object`` and ``ground`` components).

    Returns
    -------
    domain : {'edges', 'band'}
    reason : str
        One sentence naming the rule that decided.
    """
    n_planes = len(scene.planes) + (scene.ground is not None)
    if n_planes == 0:
        return "edges", "the scene has no floor or other plane, and the band domain fits a floor's band"
    if n_planes > 1:
        return "edges", (f"the scene has {n_planes} reflecting planes, and the band domain would take the "
                         "nearest plane's band for the floor's")
    obj = float(np.sum(start.components["object"], dtype=float))
    plane = float(np.sum(start.components["ground"], dtype=float))
    share = obj / (obj + plane) if obj + plane > 0 else 0.0
    if scene.objects and obj == 0:
        # Out of view at the start is no evidence that the recording does not show them.
        return "edges", (f"the scene has {len(scene.objects)} object(s), none echoing at the start pose: edges "
                         "sees them once they come into view (--domain band fits the floor alone)")
    if share > MAX_OBJECT_SHARE:
        return "edges", (f"objects carry {100 * share:.0f} % of the echo at the start pose (band needs at most "
                         f"{100 * MAX_OBJECT_SHARE:.0f} %): their edges fix the pose")
    seen = _band_beams(real)
    if seen < MIN_BAND_BEAMS:
        return "edges", (f"the recording shows a band in {100 * seen:.0f} % of its beams (band needs "
                         f"{100 * MIN_BAND_BEAMS:.0f} %)")
    rendered = _band_beams(start) if obj + plane > 0 else 1.0
    if rendered < MIN_BAND_BEAMS:
        return "edges", (f"the scene at its start pose shows a band in {100 * rendered:.0f} % of the beams "
                         f"(band needs {100 * MIN_BAND_BEAMS:.0f} %)")
    return "band", (f"the scene's echo is one floor band (objects {100 * share:.0f} % of it) and the recording "
                    f"shows a band in {100 * seen:.0f} % of its beams: its edges fix height and tilt, where "
                    "whole-image edges follow speckle")


def edge_correlation(a: SonarImage, b: SonarImage, smoothing: tuple[float, float] = CHECK_SMOOTHING) -> float:
    """Correlation, in [-1, 1], of the edge maps (:func:`edge_map`) of two images on one grid."""
    return float(np.sum(edge_map(a.polar, smoothing) * edge_map(b.polar, smoothing)))


def fit_problems(real: SonarImage, result: FitResult) -> tuple[str, ...]:
    """Why a fit is meaningless; empty when nothing shows it to be.

    The conditions, each a known way for a simplex search to end somewhere that means nothing:

    * the cost at the fitted pose is not finite, or (``band``) no beam shows a band in both
      the recording and the render;
    * the render's echo does not line up with the recording's: the correlation of their edge
      maps at :data:`CHECK_SMOOTHING` (the same in both domains) is below
      :data:`MIN_EDGE_CORRELATION`;
    * (``band``) the RMS band-edge difference exceeds :data:`MAX_BAND_RMS_FRACTION` of the
      recording's range span;
    * the search ended at a higher cost than it started; or at the start's cost, above
      :data:`PERFECT_COST`, stopped by the render budget: it never found a way downhill. (A
      search that converged onto its start is not a problem: the start was already a minimum,
      as when a fitted scene is fitted again; the band cost is flat between range bins.);
    * a free parameter moved farther from the start than the recording's far range (x, y, z)
      or :data:`MAX_ANGLE_MOVE_DEG` (angles): it ran away.

    (A render that is black at the fitted pose is not returned at all: :func:`fit_pose` raises
    :class:`FitError`.)

    Parameters
    ----------
    real : SonarImage
        The recording fitted.
    result : FitResult
        The fit.

    Returns
    -------
    tuple of str
        One short clause per problem, naming the value found and the limit.
    """
    out = []
    span = real.sonar.range_max_m - real.sonar.range_min_m
    if not np.isfinite(result.cost):
        out.append(f"the cost at the fitted pose is {result.cost}")
    elif result.domain == "band" and result.cost >= NO_BAND_COST:
        out.append("no beam shows a band in both the recording and the render")
    elif result.domain == "band" and result.cost > MAX_BAND_RMS_FRACTION * span:
        out.append(f"the band edges differ by {result.cost:.3g} m RMS (at most {MAX_BAND_RMS_FRACTION:g} of the "
                   f"{span:.3g} m window, {MAX_BAND_RMS_FRACTION * span:.3g} m, is a fit)")
    if not result.edge_correlation >= MIN_EDGE_CORRELATION:  # also NaN
        out.append(f"the render's echo does not line up with the recording's (edge correlation "
                   f"{result.edge_correlation:.2f}, at least {MIN_EDGE_CORRELATION:g} is needed)")
    if np.isfinite(result.cost) and result.cost > result.cost_start:
        out.append(f"the search ended worse than it started (cost {result.cost_start:.4g} -> {result.cost:.4g})")
    elif (np.isfinite(result.cost) and result.cost == result.cost_start and result.cost > PERFECT_COST
          and not result.converged):
        out.append(f"the search found nothing better than the start before the render budget ran out "
                   f"(cost {result.cost:.4g})")
    for name in result.free:
        moved = abs(result.values[name] - result.start[name])
        limit = MAX_ANGLE_MOVE_DEG if UNITS[name] == "deg" else real.sonar.range_max_m
        if moved > limit:
            out.append(f"{name} ran away by {moved:.3g} {UNITS[name]} (more than {limit:.3g})")
    return tuple(out)


def fit_pose(
    real: SonarImage,
    scene: Scene,
    free: Sequence[str] = ("z", "pitch"),
    domain: str = "auto",
    smoothing: Sequence[tuple[float, float]] = DEFAULT_SMOOTHING,
    max_renders: int = 600,
    simulator: Simulator | None = None,
    progress: Callable[[FitProgress], None] | None = None,
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
    domain : {'auto', 'edges', 'band'}
        What is compared (see the module docstring); ``auto``: chosen by
        :func:`choose_domain` from the scene and the recording.
    smoothing : sequence of (float, float)
        Gaussian sigmas (range bins, beams) of the coarse-to-fine passes (``edges``).
    max_renders : int
        Budget of renders over all passes.
    simulator : Simulator, optional
        Reused if given (it must hold ``scene``).
    progress : callable, optional
        Called with a :class:`FitProgress` after every render of the search.

    Returns
    -------
    FitResult
        Check :attr:`FitResult.problems` (:func:`fit_problems`) before trusting it.

    Raises
    ------
    ConfigError
        An unknown parameter or domain, or ``max_renders`` below 1.
    SonarsimError
        The recording's window is not the scene's sonar's (:func:`check_overlap`).
    FitError
        Nothing echoes inside the recording's window at the fitted pose.
    """
    free = parse_free(free)
    if domain != "auto" and domain not in DOMAINS:
        raise ConfigError("domain", f"unknown domain {domain!r}; allowed: auto, {', '.join(DOMAINS)}")
    if int(max_renders) < 1:
        raise ConfigError("max_renders", f"the render budget is {max_renders}; it must be at least 1")
    check_overlap(real, scene)
    sim = simulator if simulator is not None else Simulator(scene)
    # The intrinsics of every render (fixed): the recording's grid; only the pose varies.
    geometry = recording_geometry(real, scene)
    start = pose_values(scene.sonar_pose)
    renders = 0
    began = time.monotonic()
    stage = {"name": "", "best": float("inf")}

    def render_at(vec: np.ndarray) -> SonarImage:
        nonlocal renders
        renders += 1
        values = dict(start, **dict(zip(free, map(float, vec))))
        return sim.render(pose=pose_from_values(values), sonar=geometry, keep_rays=False)

    x0 = np.array([start[n] for n in free])
    start_image = render_at(x0)
    chosen, why = choose_domain(real, scene, start_image)
    if domain == "auto":
        domain, reason = chosen, why
    else:  # the rule's opinion costs nothing: say when it differs
        reason = "asked for" if chosen == domain else f"asked for (auto would choose {chosen}: {why})"
    real_onset, real_end = floor_band_m(real)

    def onset_rms(image: SonarImage) -> float:
        d = floor_onset_m(image) - real_onset
        return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else float("nan")

    def band_rms(image: SonarImage) -> float:
        onset, end = floor_band_m(image)
        d = np.concatenate([onset - real_onset, end - real_end])
        return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else NO_BAND_COST

    def reported(cost_of_image):
        """The cost of the image rendered at a vector, with the progress report."""
        def cost(vec):
            value = cost_of_image(render_at(vec))
            stage["best"] = min(stage["best"], value)
            if progress is not None:
                progress(FitProgress(renders, int(max_renders), stage["name"], stage["best"],
                                     time.monotonic() - began))
            return value
        return cost

    def search(cost, x, budget):
        simplex = np.vstack([x] + [x + STEPS[n] * np.eye(len(free))[i] for i, n in enumerate(free)])
        return optimize.minimize(
            cost, x, method="Nelder-Mead",
            options={"initial_simplex": simplex, "maxfev": budget, "xatol": 1e-4, "fatol": 1e-7},
        )

    if domain == "edges":
        x = x0
        for i, sigma in enumerate(smoothing):
            stage.update(name=f"edges {i + 1}/{len(smoothing)}", best=float("inf"))
            target = edge_map(real.polar, sigma)
            found = search(reported(lambda img, s=sigma, t=target: edge_cost(img.polar, t, s)), x,
                           max(1, max_renders // len(smoothing)))
            x = found.x
        finest = tuple(smoothing[-1])
        target = edge_map(real.polar, finest)

        def final_cost(image):
            return edge_cost(image.polar, target, finest)
    else:
        stage.update(name="band", best=float("inf"))
        found = search(reported(band_rms), x0, max_renders)
        x = found.x
        final_cost = band_rms
    cost_start = final_cost(start_image)
    fitted = render_at(x)
    values = dict(start, **dict(zip(free, map(float, x))))
    pose = pose_from_values(values)
    if not np.any(fitted.polar > 0):
        raise FitError("the fit found no pose at which the scene echoes inside the recording's window "
                       f"(started at {', '.join(f'{k} {start[k]:.4g}' for k in free)}): nothing to compare; "
                       "check the scene, its sonar settings and the starting pose")
    result = FitResult(
        pose=pose, scene=replace(scene, sonar=geometry, sonar_pose=pose), free=free, domain=domain, start=start, values=values,
        cost_start=cost_start, cost=final_cost(fitted), onset_rms_m=onset_rms(fitted), renders=renders,
        image=fitted, domain_reason=reason, edge_correlation=edge_correlation(real, fitted),
        converged=bool(found.success),
    )
    return replace(result, problems=fit_problems(real, result))
