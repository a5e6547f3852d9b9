"""Readers of real sonar recordings (and of sonarsim's stored frames) into sonarsim's image type.

A recording becomes the same :class:`~sonarsim.image.result.SonarImage` a simulation produces, so
that real and simulated images can be shown, compared and saved with the same code: ``polar``
is float32 ``(n_range_bins, n_beams)``, row 0 the nearest range, column 0 the LEFT-most beam
(positive azimuth = the sonar's left, so ``azimuth_deg`` descends); ``components`` is
``{"total": polar}``; ``rays`` is None; ``config`` is ``{"source", "format", "frame",
"header"}`` with the decoded header fields. Values are the recorded ones (8-bit counts for ARIS
and for 8-bit Oculus data), not calibrated intensities.

Supported, recognised from the file's first bytes (never from its name):

* ``"aris"``: Sound Metrics ARIS files (DDF_05), see :mod:`sonarsim.io.readers.aris`;
* ``"oculus"``: Blueprint Subsea Oculus simple-ping-result messages (versions 1 and 2), one or
  many back to back, as liboculus records them; see :mod:`sonarsim.io.readers.oculus`;
* ``"xtf"``: XTF side-scan recordings (sonar pings; port and starboard lines), read as
  :class:`~sonarsim.image.films.Waterfall` pings, see :mod:`sonarsim.io.readers.xtf`;
* ``"r2sonic"``: XTF files of R2Sonic multibeam bathymetry (QINSy's packets of type 65), read
  as :class:`~sonarsim.image.films.Soundings` pings, see :mod:`sonarsim.io.readers.r2sonic`;
* ``"imagenex852"``: Imagenex 852 echo-sounder files, read as
  :class:`~sonarsim.image.films.Envelope` pings, see :mod:`sonarsim.io.readers.imagenex`;
* ``"npz"``: an image sonarsim stored (``sonarsim dataset``'s ``frames/NNNNNN.npz``, ``sonarsim
  render``'s ``render.npz``, :meth:`SonarImage.save_npz`), read back as a one-frame recording
  whose frame is the stored image with its sonar and pose (not a recording's ``config``: the
  stored configuration); see :mod:`sonarsim.io.readers.npz`.

The FLS formats' frames are :class:`~sonarsim.image.result.SonarImage` polar frames; the
others' are one-ping films. Each recording class says which in its ``film`` attribute
(``"polar"``, ``"waterfall"``, ``"soundings"``, ``"envelope"``; :data:`FILMS`), so that a
program expecting polar frames can refuse the others by name. The XTF readers need the
optional ``xtf`` extra (pyxtf); recognising an XTF file does not.

Every problem with a file's content raises :class:`RecordingError` (a
:class:`~sonarsim.errors.SonarsimError`) naming the file, the frame or message and the field.
That includes header values no real sonar produces: each field the geometry comes from (sound
speed, sample period and delay, range resolution, range window, counts of beams and samples,
beam tables) is checked against limits that are module constants of the format's reader
(real devices' ranges with a wide margin), and a frame is checked against the memory budget
(:mod:`sonarsim.core.memory`) before it is read. A file that cannot be opened raises the usual
:class:`OSError`.

Damaged files. Every reader, whatever the format, follows one rule
(:class:`~sonarsim.io.readers._common.Recording`): a recording is read from its start, and the
first frame that cannot be read (cut short, a corrupt or impossible header, a frame of another
size, beyond the memory budget) ends it. The frames before it are the file's good frames, the
same everywhere: ``n_frames`` (and ``open_recording(path).n_frames``) counts them, ``read(path,
k)`` returns them and refuses every later ``k`` (frame ``n_frames`` with its own error, later
ones as out of range, naming the damage), iterating ``read_frames`` yields them and then
raises that error, and ``sonarsim show`` shows them, with a note naming the damage. An open
recording's ``damage`` is that error (``None`` when the file ends cleanly). A file whose first
frame is already unreadable holds nothing: opening it raises (so do ``read``, ``read_frames``
and ``n_frames``); a file that ends cleanly without any frame has ``n_frames == 0``, and
reading it raises.

Examples
--------
>>> from sonarsim import readers
>>> image = readers.read("sample.aris", frame=2)              # doctest: +SKIP
>>> for image in readers.read_frames("three_pings_8bit.raw"):  # doctest: +SKIP
...     print(image.polar.shape)
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Union

from ...errors import SonarsimError
from ._common import RecordingError
from .aris import ARIS_SIGNATURE, ArisRecording
from .imagenex import ImagenexRecording, imagenex_problem, is_imagenex852
from .npz import ZIP_SIGNATURE, NpzRecording
from .oculus import OCULUS_ID, OculusRecording
from .r2sonic import R2SonicRecording
from .xtf import XtfSidescanRecording, is_xtf, xtf_kind, xtf_problem

__all__ = [
    "FORMATS",
    "FILMS",
    "ArisRecording",
    "ImagenexRecording",
    "NpzRecording",
    "OculusRecording",
    "R2SonicRecording",
    "XtfSidescanRecording",
    "RecordingError",
    "detect_format",
    "n_frames",
    "open_recording",
    "read",
    "read_frames",
]

PathLike = Union[str, "os.PathLike[str]"]

# The formats recognised from their content beyond the first 16 bytes: each entry is the
# format's name, its reader class, its usual suffixes (for messages only: a file's name never
# decides) and a test of the file's first bytes (``HEAD_BYTES`` of them) and path. Adding a
# format is adding its module and one entry here.
_CONTENT_FORMATS = (
    ("xtf", XtfSidescanRecording, (".xtf",), lambda head, path: is_xtf(head) and xtf_kind(path) == "xtf",
     "XTF side-scan (.xtf, 7b ... then ce fa at byte 1024)"),
    ("r2sonic", R2SonicRecording, (".xtf",), lambda head, path: is_xtf(head) and xtf_kind(path) == "r2sonic",
     "XTF of R2Sonic bathymetry (.xtf)"),
    ("imagenex852", ImagenexRecording, (".852",), lambda head, path: is_imagenex852(head),
     "Imagenex 852 (.852, starting with '852', 'IGX' at byte 100)"),
)
#: Bytes read to recognise a format (XTF's first packet starts at byte 1024).
HEAD_BYTES = 1040

#: Format name -> reader class.
FORMATS = {"aris": ArisRecording, "oculus": OculusRecording, "npz": NpzRecording,
           **{name: cls for name, cls, *_ in _CONTENT_FORMATS}}
#: Format name -> the film its frames are (``"polar"``: SonarImage frames).
FILMS = {name: cls.film for name, cls in FORMATS.items()}

# Other files that users are likely to pass by mistake, named in the error message.
_FOREIGN = (
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"\x93NUMPY", "a NumPy .npy file"),
    (b"#ROSBAG", "a ROS 1 bag (extract the sonar topic first)"),
    (b"\x89HDF", "an HDF5 file"),
)


def detect_format(path: PathLike) -> str:
    """The format of a recording, from its first bytes.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    {"aris", "oculus", "npz", "xtf", "r2sonic", "imagenex852"}
        ``"npz"`` for any zip archive: whether it is an image sonarsim stored is found when it
        is opened.

    Raises
    ------
    RecordingError
        For an empty file, a DIDSON file (older DDF versions) or any other content.
    OSError
        If the file cannot be read.
    """
    from ...errors import check_input_file

    source = os.fspath(path)
    # A FIFO would block the open below for ever. A missing or unreadable file is left to
    # open(), whose OSError (FileNotFoundError, ...) callers of the readers expect.
    if os.path.lexists(source):
        try:
            check_input_file(path, "recording")
        except SonarsimError as exc:
            raise RecordingError(source, str(exc).split(": ", 1)[-1]) from None
    with open(path, "rb") as handle:
        head = handle.read(HEAD_BYTES)
    if not head:
        raise RecordingError(source, "the file is empty")
    if len(head) >= 4:
        word = int.from_bytes(head[:4], "little")
        if word == ARIS_SIGNATURE:
            return "aris"
        if head[:3] == b"DDF" and head[3] < 5:
            raise RecordingError(
                source,
                f"DIDSON file format DDF_0{head[3]} is not supported (only ARIS DDF_05)",
                "file header", "Version",
            )
    if len(head) >= 2 and int.from_bytes(head[:2], "little") == OCULUS_ID:
        return "oculus"
    if head.startswith(ZIP_SIGNATURE):
        return "npz"
    for name, _cls, _suffixes, test, _what in _CONTENT_FORMATS:
        if test(head, path):
            return name
    for problem in (xtf_problem(head), imagenex_problem(head)):
        if problem:
            raise RecordingError(source, problem, "file header")
    for magic, what in _FOREIGN:
        if head.startswith(magic):
            raise RecordingError(source, f"this is {what}, not a sonar recording")
    raise RecordingError(
        source,
        f"not a recognised sonar recording (first bytes {head[:8].hex(' ')}); supported: ARIS "
        f"(.aris, starting with {ARIS_SIGNATURE.to_bytes(4, 'little').hex(' ')}), Oculus "
        f"simple ping results (.raw, starting with {OCULUS_ID.to_bytes(2, 'little').hex(' ')}) "
        f"{''.join(', ' + what for *_, what in _CONTENT_FORMATS)} and images sonarsim stored (.npz)",
    )


_READ_FILM = {
    "waterfall": "sonarsim.io.readers.xtf.read_waterfall(path)",
    "soundings": "sonarsim.io.readers.r2sonic.read_soundings(path)",
    "envelope": "sonarsim.io.readers.imagenex.read_envelope(path)",
}


def open_recording(path: PathLike, film: str = "polar"):
    """Open a recording for repeated reads (a context manager; close it when done).

    Parameters
    ----------
    path : str or os.PathLike
        The file (recognised by its content).
    film : {"polar", "waterfall", "soundings", "envelope", "any"}
        The frames the caller can use. The default, ``"polar"``, opens the FLS formats (and
        stored images), whose frames are SonarImages, and refuses a side-scan, multibeam or
        single-beam recording by name (programs written for FLS frames, such as ``sonarsim
        show``, then say what the file is instead of failing on its pings); ``"any"`` opens
        every format.

    Returns
    -------
    Recording
        ArisRecording, OculusRecording, NpzRecording (``film`` "polar"), XtfSidescanRecording,
        R2SonicRecording or ImagenexRecording: with ``n_frames`` (the good frames), ``damage``
        (why the file ends there, or None), ``read(frame)``, iteration over the good frames
        and ``film``.

    Raises
    ------
    RecordingError
        Unknown content, a recording of another film than ``film``, or a first frame that
        cannot be read (nothing in the file is).
    """
    fmt = detect_format(path)
    kind = FILMS[fmt]
    if film not in ("any", *_FILM_NAMES):
        raise ValueError(f"film must be one of {', '.join(('any', *_FILM_NAMES))}, got {film!r}")
    if film not in ("any", kind):
        hint = f"; read it with {_READ_FILM[kind]} or open_recording(path, film={kind!r})" if kind in _READ_FILM else ""
        raise RecordingError(os.fspath(path), f"this {fmt} recording holds {kind} pings (sonarsim.image.films), not "
                             f"the {film} frames wanted here{hint}")
    return FORMATS[fmt](path)


_FILM_NAMES = ("polar", "waterfall", "soundings", "envelope")


def n_frames(path: PathLike, film: str = "any") -> int:
    """Number of good frames (ARIS) or simple ping results (Oculus), or pings of the other
    formats, in a recording: those before the first one that cannot be read
    (``open_recording(path).damage`` says why it cannot); ``film`` as :func:`open_recording`."""
    with open_recording(path, film) as recording:
        return recording.n_frames


def read(path: PathLike, frame: int = 0, film: str = "polar"):
    """One frame of a recording as a :class:`~sonarsim.image.result.SonarImage` (or, with
    ``film`` "any" or a film's name, one ping of a side-scan, multibeam or single-beam
    recording as a one-ping film).

    Parameters
    ----------
    path : str or os.PathLike
        An ARIS file, a file of Oculus messages or an image sonarsim stored as NPZ
        (recognised by content).
    frame : int
        0-based frame (ARIS) or ping (Oculus; other message kinds are not counted); 0 for an
        NPZ, which holds one image.
    film : str
        As :func:`open_recording` (default ``"polar"``).

    Returns
    -------
    SonarImage
        See the module notes; ``config["frame"]`` is ``frame``.

    Raises
    ------
    RecordingError
        Unknown content, a frame that is not among the good frames: truncated, corrupt, after
        such a frame, or out of range (the message gives the valid range).
    """
    with open_recording(path, film) as recording:
        return recording.read(frame)


def read_frames(path: PathLike, film: str = "polar") -> Iterator:
    """Every frame of a recording, in order, read one at a time (the file stays open meanwhile).

    The file is opened and recognised at once (a foreign file, or one whose first frame is
    unreadable, raises here, not at the first ``next``). The good frames are yielded, then the
    first frame that :func:`read` refuses raises the same error (a truncated last frame, a
    corrupt header); a file without frames raises at the first ``next`` (never an empty
    iteration). ``film`` as :func:`open_recording`.
    """
    return _frames(open_recording(path, film))


def _frames(recording) -> Iterator:
    with recording:
        yield from recording
