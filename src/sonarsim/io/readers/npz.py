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
import zipfile
import zlib
from typing import Any

import numpy as np

from ...errors import SonarsimError
from ._common import Recording, RecordingError

__all__ = ["ZIP_SIGNATURE", "NpzRecording"]

#: The first bytes of a zip archive (a local file header), hence of every NPZ.
ZIP_SIGNATURE = b"PK\x03\x04"

# What a broken or hostile archive can raise while NumPy and zipfile read it: a corrupt zip
# directory or CRC (BadZipFile), a bad .npy header or an object array (ValueError), a cut file
# (EOFError, OSError), a corrupt deflate stream (zlib.error), encrypted or exotically
# compressed entries (RuntimeError, NotImplementedError), odd header fields (struct.error,
# OverflowError, KeyError).
_ARCHIVE_ERRORS = (ValueError, OSError, EOFError, KeyError, RuntimeError, NotImplementedError,
                   OverflowError, MemoryError, zipfile.BadZipFile, zlib.error, struct.error)

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
        from ...config.loader import parse_sonar_section
        from ...image.result import SonarImage
        from ..output import CONFIG_KEY, read_npz

        try:
            arrays, config = read_npz(self._source)
        except SonarsimError as exc:  # the memory budget: its message names the sizes
            raise self._fail(getattr(exc, "detail", None) or str(exc)) from None
        except RecursionError:
            raise self._fail(f"{CONFIG_KEY} is nested too deeply to be a configuration") from None
        except _ARCHIVE_ERRORS as exc:
            detail = _printable(str(exc).replace(f"{self._source}: ", ""))
            raise self._fail(f"not a readable NPZ written by sonarsim ({type(exc).__name__}: {detail})") from None

        for name in ("polar", "range_m", "azimuth_deg"):
            if name not in arrays:
                raise self._fail(f"missing: an image written by sonarsim (render, dataset, SonarImage.save_npz) "
                                 "has polar, range_m and azimuth_deg; this file holds "
                                 f"{_printable(', '.join(sorted(arrays))) or 'no array'}", name)
            if arrays[name].dtype.kind not in "iuf":
                raise self._fail(f"holds {arrays[name].dtype} values; an image and its axes hold real numbers", name)
        polar = arrays["polar"]
        if polar.ndim != 2:
            raise self._fail(f"has shape {polar.shape}; an image has 2 dimensions (range bins x beams)", "polar")

        section = config.get("sonar")
        if not isinstance(section, dict):
            raise self._fail("has no 'sonar' section (the sonar that made the image), so the image's geometry "
                             "is unknown", CONFIG_KEY)
        if "beam_angles_file" in section:
            raise self._fail("sonar.beam_angles_file names a file; an image written by sonarsim lists its beam "
                             "angles (sonar.beam_angles_deg)", CONFIG_KEY)
        try:
            sonar, pose = parse_sonar_section(section, None)
        except SonarsimError as exc:
            raise self._fail(f"{getattr(exc, 'key', '') or 'sonar'}: {getattr(exc, 'detail', None) or exc}",
                             CONFIG_KEY) from None
        # The arrays must be the sonar's images: same cells, same axes (compared before the
        # sonar's grid is built, so that a huge configured grid is never allocated).
        shape = (sonar.n_range_bins, sonar.n_beams)
        if polar.shape != shape:
            raise self._fail(f"has shape {polar.shape}, but the configuration's sonar has {shape[0]} range bins x "
                             f"{shape[1]} beams", "polar")
        for name, axis in (("range_m", sonar.grid.range_m), ("azimuth_deg", sonar.grid.azimuth_deg)):
            stored = arrays[name]
            if stored.shape != axis.shape or not np.allclose(stored, axis, rtol=0.0, atol=1e-6):
                raise self._fail(f"is not the axis of the configuration's sonar ({axis.size} values from "
                                 f"{axis[0]:.6g} to {axis[-1]:.6g})", name)

        components = {
            name: np.asarray(value, dtype=np.float32)
            for name, value in arrays.items()
            if name != "polar" and value.shape == polar.shape and value.dtype.kind == "f"
            and not name.startswith(("rays_", *_LABEL_PREFIXES))
        }
        polar = np.asarray(polar, dtype=np.float32)
        return SonarImage(
            polar=polar,
            range_m=sonar.grid.range_m,
            azimuth_deg=sonar.grid.azimuth_deg,
            components=components,
            sonar=sonar,
            pose=pose,
            rays=None,
            config=config,
        )


def _printable(text: str, limit: int = 200) -> str:
    """``text`` on one line of printable characters, at most ``limit`` of them: error details
    can quote a hostile file's bytes (a corrupt .npy header, entry names)."""
    text = "".join(c if c.isprintable() else f"\\x{ord(c):02x}" for c in text)
    return text if len(text) <= limit else text[:limit] + "..."
