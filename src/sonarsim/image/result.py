"""The result types: a sonar image in polar form (:class:`SonarImage`) and its per-ray maps.

Renders and real recordings (:mod:`sonarsim.io.readers`) give the same :class:`SonarImage`, so
everything downstream (fan, files, comparison, fitting) treats both alike.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..core.transforms import Pose
from .display import hook, image_repr
from .fan import FanMapper
from .grid import PolarGrid, PolarSonar
from .labels import FanLabels, Labels
from .units import Unit, unit_of



@dataclass(frozen=True)
class RayMaps:
    """The paper's intermediate forms, one entry per ray.

    Arrays are shaped ``(n_beams, n_azimuth_samples, n_elevation_samples)``: beam left-most
    first, elevation ascending.

    Attributes
    ----------
    distance_m : float32 ndarray
        D_f: range of the first surface hit, metres; ``inf`` for none.
    intensity : float32 ndarray
        I_f: backscattered energy of the ray (what Algorithm 1 accumulates).
    surface_id : int16 ndarray
        -1 nothing, 0 the ground, k + 1 the scene's object k (ground-truth labels).
    azimuth_deg : (n_beams, n_azimuth_samples) ndarray
    elevation_deg : (n_elevation_samples,) ndarray
    """

    distance_m: np.ndarray
    intensity: np.ndarray
    surface_id: np.ndarray
    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray


@dataclass(frozen=True)
class SonarImage:
    """A rendered (or recorded) sonar image in polar form, with its axes and components.

    Attributes
    ----------
    polar : (n_range_bins, n_beams) float32 ndarray
        The image: ``components["total"]``, times speckle when ``render.speckle`` is on. Row 0
        is the nearest range bin, column 0 the left-most beam.
    range_m : (n_range_bins,) float64 ndarray
        Centre of each range bin, metres.
    azimuth_deg : (n_beams,) float64 ndarray
        Centre of each beam, degrees, left-most first (descending).
    components : mapping of str to (n_range_bins, n_beams) float32 ndarray
        The table of :mod:`sonarsim.renderer.components`: ``object``, ``ground`` (the planes'
        direct echo), ``single`` (= object + ground), one image per path order (``double``,
        ``triple``, ``order4``, ...) and ``total`` (= ``polar`` without speckle: the orders
        selected by ``render.bounces``); then one image per path signature, named by
        :func:`sonarsim.paths.engine.path_name` (e.g. ``O-ground-[objects]-ground-O``). All
        are formed whatever enters the total, so that each is available as a label.
    sonar : SonarConfig
        The sonar's intrinsics (beams, elevation aperture, range window) that produced the image
        (typed as :class:`~sonarsim.image.grid.PolarSonar`, what the image needs of it: this
        package does not import :mod:`sonarsim.config`, which builds its grid from here).
    pose : Pose or None
        The sonar's pose in the world frame (sonar-to-world); ``None`` where it is unknown,
        as for a real recording read by :mod:`sonarsim.io.readers`.
    rays : RayMaps or None
        Per-ray distance and intensity maps (D_f, I_f) and surface labels.
    config : dict
        The full scene configuration, in scene-file form.
    labels : Labels or None
        The frame's ground truth (``Simulator.render(..., labels=True)``; see
        :mod:`sonarsim.image.labels`); ``None`` otherwise and for recordings.
    """

    polar: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    components: Mapping[str, np.ndarray]
    sonar: PolarSonar
    pose: Pose | None = None
    rays: RayMaps | None = None
    config: dict = field(default_factory=dict)
    labels: Labels | None = None

    @property
    def grid(self) -> PolarGrid:
        """The polar grid of :attr:`polar` (the sonar's)."""
        return self.sonar.grid

    @property
    def range_edges_m(self) -> np.ndarray:
        """(n_range_bins + 1,) range bin edges, metres."""
        return self.sonar.range_edges_m

    @property
    def unit(self) -> Unit:
        """What :attr:`polar`'s values are (:mod:`sonarsim.image.units`): ``backscatter``
        (sigma / r^2 per bin), ``backscatter_per_r2`` (TVG off), ``uPa^2`` (a sensor without
        output) or ``counts`` (a device's output, a recording)."""
        return unit_of(self.config)

    def fan(self, pixel_size_m: float | None = None, component: str | None = None, interpolation: str = "linear"):
        """The fan-shaped Cartesian image (see :func:`sonarsim.image.fan.polar_to_fan`).

        Parameters
        ----------
        pixel_size_m : float, optional
            Pixel edge, metres; default the range resolution.
        component : str, optional
            A key of :attr:`components`; default the total image.
        interpolation : {'linear', 'nearest'}
        """
        img = self.polar if component is None else self.components[component]
        return _fan_mapper(self.sonar.grid, pixel_size_m, interpolation)(img)

    def fan_levels(self, polar_levels: np.ndarray, pixel_size_m: float | None = None) -> np.ndarray:
        """8-bit display levels made on the polar grid (``to_uint8`` or
        :func:`~sonarsim.image.levels.default_levels` of :attr:`polar` or a component),
        resampled to the fan of :meth:`fan` (:meth:`FanMapper.levels
        <sonarsim.image.fan.FanMapper.levels>`: the mapping on the grid's cells, not the fan's
        pixels; one compiled gather).

        Parameters
        ----------
        polar_levels : (n_range_bins, n_beams) uint8 array
            Nearest range first (as :attr:`polar`).
        pixel_size_m : float, optional
            As :meth:`fan`.

        Returns
        -------
        (height, width) uint8 ndarray
            The fan, far range at the top, 0 outside it.
        """
        return _fan_mapper(self.sonar.grid, pixel_size_m, "linear").levels(polar_levels)

    def fan_labels(self, pixel_size_m: float | None = None) -> FanLabels:
        """The labels resampled to the fan image of :meth:`fan` (nearest neighbour).

        Parameters
        ----------
        pixel_size_m : float, optional
            Pixel edge, metres; default the range resolution (as :meth:`fan`).

        Raises
        ------
        ValueError
            The image has no labels (render with ``labels=True``).
        """
        if self.labels is None:
            raise ValueError("this image has no labels: render it with labels=True")
        return self.labels.fan(_fan_mapper(self.sonar.grid, pixel_size_m, "nearest"))

    def arrays(self) -> dict[str, np.ndarray]:
        """Everything as named arrays (what the NPZ file holds, less the configuration).

        With labels, their arrays too (:meth:`sonarsim.image.labels.Labels.arrays`: ``instance``,
        ``elevation_deg``, ``points_world``, ``points_object``, ...).
        """
        out = {"polar": self.polar, "range_m": self.range_m, "azimuth_deg": self.azimuth_deg}
        out.update(self.components)
        if self.rays is not None:
            out.update(
                rays_distance_m=self.rays.distance_m,
                rays_intensity=self.rays.intensity,
                rays_surface_id=self.rays.surface_id,
                rays_azimuth_deg=self.rays.azimuth_deg,
                rays_elevation_deg=self.rays.elevation_deg,
            )
        if self.labels is not None:
            clash = set(out) & set(self.labels.arrays())
            if clash:  # a path-signature name cannot take these forms, but say so if it ever does
                raise ValueError(f"label arrays would overwrite {sorted(clash)}")
            out.update(self.labels.arrays())
        return out

    def save_npz(self, path) -> None:
        """Write :meth:`arrays`, the image's ``unit`` (a string: :attr:`unit`'s name) and the
        configuration to an NPZ file, atomically (:func:`sonarsim.io.output.write_npz`)."""
        hook("write_npz", "SonarImage.save_npz")(path, {**self.arrays(), "unit": np.array(self.unit.name)}, self.config)

    # -- pictures (sonarsim.plot, through the hooks of sonarsim.image.display; matplotlib is
    # imported only when a picture is made) ----------------------------------------------------

    def __repr__(self) -> str:
        # One or two lines: the arrays' text would run to pages.
        return image_repr(self)

    def _repr_png_(self) -> bytes:
        """What a notebook shows: the small annotated fan figure."""
        return hook("image_repr_png", "SonarImage._repr_png_")(self)

    def plot(self, ax=None, *, kind: str = "fan", component: str | None = None, **options):
        """Draw the annotated figure (fan in metres, or polar) on ``ax`` and return the axes.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Default: a new pyplot figure (shown by a notebook).
        kind : {'fan', 'polar'}
        component : str, optional
            A key of :attr:`components` (default: the image).
        **options
            For :func:`sonarsim.plot.figures.fan_figure`: ``colormap`` (``"grey"`` for grey),
            ``mapping``, ``gain_db``, ``dynamic_range_db``, ``pixel_size_m``, ``title``, ...

        Returns
        -------
        matplotlib.axes.Axes
        """
        return hook("image_plot", "SonarImage.plot")(self, ax, kind, component, **options)

    def save(self, path, *, kind: str = "fan", component: str | None = None, **options) -> None:
        """Write the annotated figure to ``path``: PNG, SVG or PDF after its suffix, atomically.

        The options are those of :meth:`plot`.
        """
        hook("image_save", "SonarImage.save")(self, path, kind, component, **options)

    def to_pil(self, *, kind: str = "fan", component: str | None = None, **options):
        """The exact-pixel image as a PIL image (8-bit grey, as the commands' PNGs).

        Parameters
        ----------
        kind : {'fan', 'polar'}
            The fan at the range resolution (0 outside it), or the polar image with far range at
            the top.
        component : str, optional
        **options
            ``mapping``, ``gain_db``, ``dynamic_range_db``, ``pixel_size_m`` (see
            :func:`sonarsim.plot.notebook.image_to_pil`).

        Returns
        -------
        PIL.Image.Image
        """
        return hook("image_to_pil", "SonarImage.to_pil")(self, kind, component, **options)


@functools.lru_cache(maxsize=8)
def _fan_mapper(grid: PolarGrid, pixel_size_m: float | None, interpolation: str) -> FanMapper:
    """Scan-conversion tables are costly to build and the same for every frame of a sonar."""
    return FanMapper.from_grid(grid, pixel_size_m, interpolation)
