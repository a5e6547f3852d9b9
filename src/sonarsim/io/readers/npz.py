"""Reader of the frames sonarsim stores as NPZ files, so that they open like recordings.

``sonarsim dataset`` writes each frame as ``frames/NNNNNN.npz``, ``sonarsim render`` and
``sonarsim demo`` write ``render.npz`` and :meth:`SonarImage.save_npz` any image: a zip of
``.npy`` arrays (``polar``, ``range_m``, ``azimuth_deg``, the components, labels, ...) and the
configuration as JSON text (``config_json``, :func:`sonarsim.io.output.write_npz`). Read here,
such a file is a one-frame recording whose frame is the stored
:class:`~sonarsim.image.result.SonarImage`: its ``polar`` and components as stored, its ``sonar``
(the exact intrinsics, parsed from the configuration's ``sonar`` section) and ``pose``, its
``config`` the stored configuration. So ``sonarsim.read``, ``read_frames``, ``open_recording``
and ``sonarsim show`` open it as they open an ARIS or Oculus file. The labels, per-ray maps and
points stay in the file (``sonarsim.io.output.read_npz`` gives every array).

An NPZ from elsewhere is not trusted: it is loaded without pickle (object arrays are refused),
the sizes its arrays declare are checked against the memory budget before anything is
allocated (:func:`sonarsim.io.output.read_npz`), and every problem - a broken archive, no
configuration or no ``sonar`` section in it, arrays missing, of the wrong kind or shape, axes
that are not the sonar's - ends in one :class:`RecordingError` naming the file and what is
wrong. The configuration's ``sonar`` section may not name a beam-angle file (a stored image
lists its angles): reading a file must not make sonarsim open another one.
"""

from __future__ import annotations

import struct
import tokenize
import zipfile
import zlib
from typing import Any

import numpy as np

from ...errors import SonarsimError
from ._common import Recording, RecordingError

__all__ = ["ZIP_SIGNATURE", "NpzRecording", "echo_components", "load_stored_image", "range_window"]

#: The first bytes of a zip archive (a local file header), hence of every NPZ.
ZIP_SIGNATURE = b"PK\x03\x04"

# What a broken or hostile archive can raise while NumPy and zipfile read it: a corrupt zip
# directory or CRC (BadZipFile), a bad .npy header or an object array (ValueError), a cut file
# (EOFError, OSError), a corrupt deflate stream (zlib.error), encrypted or exotically
# compressed entries (RuntimeError, NotImplementedError), odd header fields (struct.error,
# OverflowError, KeyError).
# (SyntaxError and tokenize.TokenError: NumPy parses an .npy header with ``ast.literal_eval``
# after tokenizing it; a header cut or mangled mid-dict raises those, not ValueError.)
_ARCHIVE_ERRORS = (ValueError, OSError, EOFError, KeyError, RuntimeError, NotImplementedError,
                   OverflowError, MemoryError, zipfile.BadZipFile, zlib.error, struct.error, SyntaxError,
                   tokenize.TokenError)

# Arrays of a frame that are labels, not echo images, though some share the image's shape and
# dtype (Labels.arrays(): instance maps and elevation maps); per-ray maps start with "rays_".
_LABEL_PREFIXES = ("instance", "elevation")


class NpzRecording(Recording):
    """An image sonarsim stored as an NPZ file, as a recording of one frame.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.npz`` file (recognised by its content, whatever its name).

    Raises
    ------
    RecordingError
        If the file is not an NPZ that sonarsim wrote for an image (see the module notes).
    OSError
        If the file cannot be opened.

    Examples
    --------
    >>> image = sonarsim.read("dataset/frames/000012.npz")     # doctest: +SKIP
    >>> image.sonar, image.pose, image.components["triple"]     # doctest: +SKIP
    """

    format = "npz"

    def _open(self) -> None:
        self._loaded: Any = None  # frame 0, decoded by _check; handed out by the first _read

    def _check(self, k: int) -> bool:
        if k > 0:
            return False
        # The whole file is checked before the frame counts as good: a file refused here is
        # refused when opened (as a recording whose first frame is unreadable).
        self._loaded = self._load()
        return True

    def _read(self, k: int):
        # The image decoded when the file was checked goes to the first caller; later reads
        # decode the file again, so that no two callers share (and may change) the same arrays.
        image, self._loaded = self._loaded, None
        return image if image is not None else self._load()

    def read(self, frame: int = 0):
        """The stored image (``frame`` 0, the only one) as a :class:`~sonarsim.image.result.SonarImage`.

        Returns
        -------
        SonarImage
            ``polar`` (float32), ``range_m`` and ``azimuth_deg`` (the sonar's axes, equal to
            the stored ones), ``components`` (every stored float image of the polar shape but
            the labels and per-ray maps), ``sonar`` and ``pose`` from the configuration's
            ``sonar`` section, ``config`` the stored configuration, ``rays`` and ``labels``
            None.

        Raises
        ------
        RecordingError
            ``frame`` other than 0.
        """
        return super().read(frame)

    # -- decoding ----------------------------------------------------------------------------

    def _fail(self, message: str, field: str | None = None) -> RecordingError:
        return RecordingError(self._source, message, None, field)

    def _load(self):
        return load_stored_image(self._source)


def _printable(text: str, limit: int = 200) -> str:
    """``text`` on one line of printable characters, at most ``limit`` of them: error details
    can quote a hostile file's bytes (a corrupt .npy header, entry names)."""
    text = "".join(c if c.isprintable() else f"\\x{ord(c):02x}" for c in text)
    return text if len(text) <= limit else text[:limit] + "..."


#: The elevation aperture a stored image is given when its configuration names none
#: (``geometry="axes"``): the default of :class:`~sonarsim.config.sonar.SonarConfig`'s presets.
DEFAULT_ELEVATION_FOV_DEG = 14.0


def echo_components(arrays: dict[str, np.ndarray], shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """The echo components among a stored frame's arrays: every float image of the polar
    ``shape`` but ``polar`` itself, the per-ray maps (``rays_*``) and the label maps
    (``instance*``, ``elevation*_deg``: :meth:`~sonarsim.image.labels.Labels.arrays`), as
    float32. The one rule for every reader of stored images (``sonarsim.read``, ``show``,
    ``compare``)."""
    return {
        name: np.asarray(value, dtype=np.float32)
        for name, value in arrays.items()
        if name != "polar" and value.shape == tuple(shape) and value.dtype.kind == "f"
        and not name.startswith(("rays_", *_LABEL_PREFIXES))
    }


def range_window(range_m: np.ndarray) -> tuple[float, float]:
    """``(range_min_m, range_max_m)`` from uniformly spaced range bin centres (m).

    Raises
    ------
    ValueError
        Fewer than two centres, or centres that are not uniformly spaced and increasing.
    """
    r = np.asarray(range_m, dtype=np.float64).ravel()
    if r.size < 2:
        raise ValueError(f"cannot recover the range window from {r.size} range bin centre(s)")
    step = np.diff(r)
    dr = float(r[-1] - r[0]) / (r.size - 1)
    # Bins are uniform by the project's convention; anything else is not a sonarsim image.
    if not (dr > 0 and np.allclose(step, dr, rtol=1e-6, atol=1e-9)):
        raise ValueError("range_m must be uniformly spaced, increasing bin centres")
    # Rounded to 12 significant digits so that a window such as 0.5-5 m comes back as exactly
    # that rather than 0.49999999999999994 (float round-off of centre - dr/2); the change is
    # far below any meaningful range.
    return float(f"{r[0] - dr / 2.0:.12g}"), float(f"{r[-1] + dr / 2.0:.12g}")


def load_stored_image(path: Any, component: str | None = None, *, geometry: str = "config"):
    """Read an image sonarsim stored as NPZ: the one loader of ``sonarsim.read``, ``show`` and
    ``compare`` (see the module notes for what is checked).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.npz`` file.
    component : str, optional
        The stored array to return as the image instead of ``polar`` (``"single"``,
        ``"triple"``, a path signature); it must be an echo component
        (:func:`echo_components`), not a label map.
    geometry : {'config', 'axes'}
        ``'config'``: the sonar is the configuration's ``sonar`` section, which must exist and
        match the stored axes (the exact intrinsics; ``sonarsim.read``, ``show``). ``'axes'``:
        the sonar is rebuilt from the axes (range window from the uniform bin centres, beam
        table from ``azimuth_deg``) and the configuration's ``sonar.elevation_fov_deg``
        (:data:`DEFAULT_ELEVATION_FOV_DEG` if absent), ``beam_width_deg`` and
        ``frequency_khz``; its pose is ``sonar.pose`` where it parses (``compare``: any image
        with axes compares).

    Returns
    -------
    SonarImage
        ``polar`` (float32: the stored image or ``component``), ``range_m`` and
        ``azimuth_deg``, ``components`` (:func:`echo_components`), ``sonar``, ``pose``,
        ``config`` the stored configuration; ``rays`` and ``labels`` None.

    Raises
    ------
    RecordingError
        Naming the file (and the array or entry at fault): not an NPZ sonarsim wrote, arrays
        missing or not real numbers, shapes or axes that disagree, an unknown component, an
        image holding NaN or infinities, sizes beyond the memory budget.
    """
    import os

    from ...image.result import SonarImage
    from ..output import CONFIG_KEY, read_npz

    source = os.fspath(path)

    def fail(message: str, field: str | None = None) -> RecordingError:
        return RecordingError(source, message, None, field)

    if geometry not in ("config", "axes"):
        raise ValueError(f"geometry must be 'config' or 'axes', got {geometry!r}")
    try:
        arrays, config = read_npz(source)
    except SonarsimError as exc:  # the memory budget: its message names the sizes
        raise fail(getattr(exc, "detail", None) or str(exc)) from None
    except RecursionError:
        raise fail(f"{CONFIG_KEY} is nested too deeply to be a configuration") from None
    except _ARCHIVE_ERRORS as exc:
        detail = _printable(str(exc).replace(f"{source}: ", ""))
        raise fail(f"not a readable NPZ written by sonarsim ({type(exc).__name__}: {detail})") from None

    for name in ("polar", "range_m", "azimuth_deg"):
        if name not in arrays:
            raise fail(f"missing: an image written by sonarsim (render, dataset, SonarImage.save_npz) "
                       "has polar, range_m and azimuth_deg; this file holds "
                       f"{_printable(', '.join(sorted(arrays))) or 'no array'}", name)
        if arrays[name].dtype.kind not in "iuf":
            raise fail(f"holds {arrays[name].dtype} values; an image and its axes hold real numbers", name)
    polar = arrays["polar"]
    if polar.ndim != 2:
        raise fail(f"has shape {polar.shape}; an image has 2 dimensions (range bins x beams)", "polar")
    components = echo_components(arrays, polar.shape)
    if component is not None and component != "polar" and component not in components:
        label = " (a label map, not an echo image)" if component in arrays else ""
        raise fail(f"no image {_printable(repr(component))}{label}; the file holds "
                   f"{_printable(', '.join(['polar', *sorted(components)]))}")
    key = "polar" if component is None else component
    image = polar if key == "polar" else arrays[key]
    finite = np.isfinite(image)
    if not finite.all():
        bad = int(finite.size - np.count_nonzero(finite))
        raise fail(f"holds NaN or infinite values ({bad} of {finite.size} pixels); a sonar image holds finite "
                   "numbers", key)

    if geometry == "config":
        sonar, pose = _configured_sonar(config, polar, arrays, fail)
        range_m, azimuth = sonar.grid.range_m, sonar.grid.azimuth_deg
    else:
        sonar, pose = _sonar_from_axes(config, polar, arrays, fail)
        range_m = np.asarray(arrays["range_m"], dtype=np.float64).ravel()
        azimuth = np.asarray(arrays["azimuth_deg"], dtype=np.float64).ravel()
    return SonarImage(polar=np.asarray(image, dtype=np.float32), range_m=range_m, azimuth_deg=azimuth,
                      components=components, sonar=sonar, pose=pose, rays=None, config=config)


def _configured_sonar(config: dict, polar: np.ndarray, arrays: dict, fail):
    """The configuration's sonar and pose, checked against the stored image and axes."""
    from ...config.loader import parse_sonar_section
    from ..output import CONFIG_KEY

    section = config.get("sonar")
    if not isinstance(section, dict):
        raise fail("has no 'sonar' section (the sonar that made the image), so the image's geometry "
                   "is unknown", CONFIG_KEY)
    if "beam_angles_file" in section:
        raise fail("sonar.beam_angles_file names a file; an image written by sonarsim lists its beam "
                   "angles (sonar.beam_angles_deg)", CONFIG_KEY)
    try:
        sonar, pose = parse_sonar_section(section, None)
    except SonarsimError as exc:
        raise fail(f"{getattr(exc, 'key', '') or 'sonar'}: {getattr(exc, 'detail', None) or exc}",
                   CONFIG_KEY) from None
    # The arrays must be the sonar's images: same cells, same axes (compared before the
    # sonar's grid is built, so that a huge configured grid is never allocated).
    shape = (sonar.n_range_bins, sonar.n_beams)
    if polar.shape != shape:
        raise fail(f"has shape {polar.shape}, but the configuration's sonar has {shape[0]} range bins x "
                   f"{shape[1]} beams", "polar")
    for name, axis in (("range_m", sonar.grid.range_m), ("azimuth_deg", sonar.grid.azimuth_deg)):
        stored = arrays[name]
        if stored.shape != axis.shape or not np.allclose(stored, axis, rtol=0.0, atol=1e-6):
            raise fail(f"is not the axis of the configuration's sonar ({axis.size} values from "
                       f"{axis[0]:.6g} to {axis[-1]:.6g})", name)
    return sonar, pose


def _sonar_from_axes(config: dict, polar: np.ndarray, arrays: dict, fail):
    """A sonar rebuilt from the stored axes (and what the configuration says of the rest)."""
    from ...config.sonar import SonarConfig
    from ..output import CONFIG_KEY

    range_m = np.asarray(arrays["range_m"], dtype=np.float64).ravel()
    azimuth = np.asarray(arrays["azimuth_deg"], dtype=np.float64).ravel()
    if polar.shape != (range_m.size, azimuth.size):
        raise fail(f"has shape {polar.shape} but range_m and azimuth_deg give ({range_m.size}, {azimuth.size})",
                   "polar")
    try:
        window = range_window(range_m)
    except ValueError as exc:
        raise fail(str(exc), "range_m") from None
    s = config.get("sonar") if isinstance(config.get("sonar"), dict) else {}
    kwargs: dict[str, Any] = {}
    for k in ("beam_width_deg", "frequency_khz"):
        if isinstance(s.get(k), (int, float)) and not isinstance(s.get(k), bool):
            kwargs[k] = float(s[k])
    pose = None
    if isinstance(s.get("pose"), dict):
        from ...config.loader import parse_pose

        try:
            pose = parse_pose(s["pose"], "sonar.pose")
        except SonarsimError:
            pass  # the pose plays no part in a comparison; a bad one must not block it
    elevation = s.get("elevation_fov_deg", DEFAULT_ELEVATION_FOV_DEG)
    if isinstance(elevation, bool) or not isinstance(elevation, (int, float)):
        from ...errors import shown

        raise fail(f"sonar.elevation_fov_deg is {shown(elevation)}; allowed: a number of degrees in (0, 180)",
                   CONFIG_KEY)
    try:
        sonar = SonarConfig(beam_angles_deg=tuple(azimuth), elevation_fov_deg=float(elevation),
                            range_min_m=window[0], range_max_m=window[1], n_range_bins=int(range_m.size), **kwargs)
    except (SonarsimError, TypeError, ValueError) as exc:
        raise fail(f"inconsistent sonar geometry: {getattr(exc, 'detail', None) or exc}") from None
    return sonar, pose
