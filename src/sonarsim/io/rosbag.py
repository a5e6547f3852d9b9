"""ROS 2 bags of rendered frames, written with the pure-Python ``rosbags`` library (no ROS install).

A bag written by :class:`BagWriter` holds, per frame (all messages share the frame's stamp):

================= ======================================== ============================================
topic             type                                     content
================= ======================================== ============================================
/sonar/image      marine_acoustic_msgs/ProjectedSonarImage the polar image (see the conventions below)
/sonar/fan        sensor_msgs/Image                        the fan image (optional): mono8 or 32FC1
/sonar/pose       geometry_msgs/PoseStamped                the sonar's pose in the world frame
/tf               tf2_msgs/TFMessage                       world -> sonar (the pose), sonar -> sonar_image
/sonar/points     sensor_msgs/PointCloud2                  ground-truth points (optional): x, y, z, object
/sonar/image/unit std_msgs/String                          the image's unit, with the first frame and
                                                           whenever it changes (:mod:`sonarsim.image.units`)
================= ======================================== ============================================

``ProjectedSonarImage`` has no field for what its values are (the community's SonarInfo
proposal asks for one); ``/sonar/image/unit`` says it beside the image (``backscatter``,
``backscatter_per_r2``, ``uPa^2`` or ``counts``), stamped like the frame it first applies to:
a subscriber keeps the last one it received.

Frames (names configurable with :class:`BagFrameIds`)
-----------------------------------------------------
Their names and the topics above (:class:`BagTopics`) are set from Python, from a scenario's
``rosbag: {frame_ids: {world: map}, topics: {image: /oculus/image}}`` section, or with
``sonarsim dataset --frame-ids world=map --topics image=/oculus/image`` (:func:`bag_naming`).

``world``
    The scene's world frame (right-handed, z up).
``sonar``
    sonarsim's sonar frame (DESIGN.md section 1, ROS REP-103): x forward along the acoustic
    axis, y to the sonar's left, z up. ``/sonar/pose`` and the ``world -> sonar`` transform are
    exactly :class:`~sonarsim.core.transforms.Pose` (sonar-to-world).
``sonar_image``
    The frame of ``ProjectedSonarImage``: Z forward in the fan plane, X up, so Y = Z x X points
    to the sonar's RIGHT. It is the ``sonar`` frame rotated by 180 degrees about
    (x + z) / sqrt(2) (:data:`SONAR_TO_IMAGE_QUAT_XYZW`); ``/tf`` carries that constant transform
    in every message (rather than once on ``/tf_static``, whose latching needs QoS settings that
    bag players do not all honour).

Conventions of ``ProjectedSonarImage`` (peers get both wrong)
--------------------------------------------------------------
* Beam directions: unit vectors in the ``sonar_image`` frame. A beam at azimuth theta (positive
  to the sonar's LEFT, as everywhere in sonarsim) has direction
  ``(x, y, z) = (0, -sin theta, cos theta)``; a consumer recovers theta = atan2(-y, z). The
  left-most beam (column 0 of sonarsim's polar image, theta > 0) therefore has y < 0.
  Beams are written in sonarsim's order, left-most first (not reversed).
* Data order: ``image.data`` is range-major, ``index = range_bin * beam_count + beam``, which
  is sonarsim's polar layout ``(n_range_bins, n_beams)`` in C order: ``data[0:beam_count]`` is
  the NEAREST range bin. Bytes are little-endian (``is_bigendian = False``); ``dtype`` is the
  message's constant for the array's type (``DTYPE_FLOAT32 = 8`` for float32 images,
  ``DTYPE_UINT8 = 0`` for a device model's 8-bit output).
* ``ranges``: range-bin centres, metres, nearest first. ``ping_info.frequency`` in Hz (0 when
  unknown), ``sound_speed`` in m/s, ``tx_beamwidths`` / ``rx_beamwidths`` one per beam in
  radians. sonarsim writes the transmit beamwidth as the elevation aperture (the fan's
  vertical extent, which the transmitter sets) and the receive beamwidth as each beam's
  azimuth width (what the receive beamformer sets); see :func:`frame_from_image`.
* ``header.stamp``: the frame's transmit time.

Time: every message of a frame (header stamps, both TF transforms) and its bag time carry the
frame's stamp. A dataset's bag stamps its first frame at a start time the user sets
(:func:`parse_start_time`: ``sonarsim dataset --start-time``, a scenario's ``start_time``), by
default :data:`DEFAULT_START_TIME` (2000-01-01T00:00:00Z: not zero, which tf2 reads as "the
latest", and fixed, so that bags of the same scenario are byte-identical), and the others after
it as the frame times say (:func:`frame_stamps`).

Files: ``BagWriter(path)`` writes the bag into a temporary folder next to ``path`` and renames it
to ``path`` only when the ``with`` block ends without error; a killed or failed run leaves no
bag under the final name (at most a hidden ``.NAME.sonarsim-PID-XXXX.tmp`` folder, which
:func:`remove_abandoned_bags` clears once that process is gone). ``rosbags`` cannot append to
a bag, so a resumed run rewrites the whole bag.

``rosbags`` is optional: the ``ros`` extra (``pip install -e '.[ros]'`` in a clone, ``pip install
'sonarsim[ros]'`` for an installed package: :func:`sonarsim.core.extras.install_command`). Importing this module works without
it; opening a :class:`BagWriter` without it raises :class:`~sonarsim.errors.SonarsimError`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import re
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType, TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.extras import install_hint
from ..core.transforms import Pose
from ..errors import ConfigError, SonarsimError, shown
from .output import TEMP_MARK, temp_prefix

if TYPE_CHECKING:
    from ..image.result import SonarImage

__all__ = [
    "BAG_NAMING_KEYS",
    "BAG_STORAGES",
    "DEFAULT_START_NS",
    "DEFAULT_START_TIME",
    "SONAR_TO_IMAGE_QUAT_XYZW",
    "TOPICS",
    "BagFrame",
    "BagFrameIds",
    "BagTopics",
    "BagWriter",
    "FrameMessages",
    "MSGTYPES",
    "bag_naming",
    "beam_directions",
    "device_polar",
    "format_stamp",
    "frame_from_image",
    "frame_stamps",
    "parse_start_time",
    "remove_abandoned_bags",
]

#: Storage plugins a bag can be written with (``--rosbag mcap`` or ``--rosbag sqlite3``).
BAG_STORAGES = ("mcap", "sqlite3")

#: Topic of each message of a frame.
TOPICS: Mapping[str, str] = MappingProxyType({
    "image": "/sonar/image",
    "fan": "/sonar/fan",
    "pose": "/sonar/pose",
    "tf": "/tf",
    "points": "/sonar/points",
    "unit": "/sonar/image/unit",
})

_S = math.sqrt(0.5)
#: Rotation of the ``sonar_image`` frame (Z forward, X up) relative to the ``sonar`` frame
#: (x forward, y left, z up): 180 degrees about (x + z) / sqrt(2), i.e. the matrix
#: ``[[0, 0, 1], [0, -1, 0], [1, 0, 0]]`` (symmetric, its own inverse).
SONAR_TO_IMAGE_QUAT_XYZW = (_S, 0.0, _S, 0.0)


# Message definitions written from the field lists of marine_acoustic_msgs (BSD-3,
# apl-ocean-engineering/marine_msgs); only the fields matter to the wire format and the type
# hash, so these carry our own comments.
_MSG_DEFS: dict[str, str] = {
    "marine_acoustic_msgs/msg/PingInfo": """
# Acoustic settings of one ping.
float32 frequency      # carrier, Hz
float32 sound_speed    # m/s
float32[] tx_beamwidths  # radians, one per beam
float32[] rx_beamwidths  # radians, one per beam
""",
    "marine_acoustic_msgs/msg/SonarImageData": """
# Element types of data
uint32 DTYPE_UINT8=0
uint32 DTYPE_INT8=1
uint32 DTYPE_UINT16=2
uint32 DTYPE_INT16=3
uint32 DTYPE_UINT32=4
uint32 DTYPE_INT32=5
uint32 DTYPE_UINT64=6
uint32 DTYPE_INT64=7
uint32 DTYPE_FLOAT32=8
uint32 DTYPE_FLOAT64=9

bool is_bigendian
uint32 dtype
uint32 beam_count
uint8[] data           # range-major: index = range_bin * beam_count + beam
""",
    "marine_acoustic_msgs/msg/ProjectedSonarImage": """
# A sonar image whose beams are given as directions in the header's frame (Z forward, X up).
std_msgs/Header header
PingInfo ping_info
geometry_msgs/Vector3[] beam_directions
float32[] ranges       # range-bin centres, metres
SonarImageData image
""",
}

# numpy type -> SonarImageData.dtype constant.
_SONAR_DTYPES: dict[np.dtype, int] = {
    np.dtype(np.uint8): 0, np.dtype(np.int8): 1, np.dtype(np.uint16): 2, np.dtype(np.int16): 3,
    np.dtype(np.uint32): 4, np.dtype(np.int32): 5, np.dtype(np.uint64): 6, np.dtype(np.int64): 7,
    np.dtype(np.float32): 8, np.dtype(np.float64): 9,
}
# sensor_msgs/Image encodings of the fan image.
_FAN_ENCODINGS: dict[np.dtype, str] = {np.dtype(np.uint8): "mono8", np.dtype(np.float32): "32FC1"}
# sensor_msgs/PointField datatypes.
_POINTFIELD_FLOAT32 = 7
_POINTFIELD_INT32 = 5
# Message type of each topic (keys of TOPICS).
_MSGTYPES = {
    "image": "marine_acoustic_msgs/msg/ProjectedSonarImage",
    "fan": "sensor_msgs/msg/Image",
    "pose": "geometry_msgs/msg/PoseStamped",
    "tf": "tf2_msgs/msg/TFMessage",
    "points": "sensor_msgs/msg/PointCloud2",
    "unit": "std_msgs/msg/String",
}
#: The ROS 2 message type of each topic of a frame (keys of :data:`TOPICS`).
MSGTYPES: Mapping[str, str] = MappingProxyType(_MSGTYPES)
# One point of /sonar/points: x, y, z (float32, world frame, metres) and object id (int32).
_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("object", "<i4")])


# Frames -------------------------------------------------------------------------------------

_FRAME_ID_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_/]*$")


@dataclass(frozen=True)
class BagFrameIds:
    """Names of the coordinate frames in a bag (``header.frame_id`` and the TF tree).

    Attributes
    ----------
    world : str
        The world frame (``"world"``; ``"map"`` for stacks that expect it).
    sonar : str
        sonarsim's sonar frame (x forward, y left, z up): the pose's child frame.
    image : str
        The ``ProjectedSonarImage`` frame (Z forward, X up), a child of ``sonar``.
    """

    world: str = "world"
    sonar: str = "sonar"
    image: str = "sonar_image"

    def __post_init__(self) -> None:
        names = {"world": self.world, "sonar": self.sonar, "image": self.image}
        for key, name in names.items():
            if not isinstance(name, str) or not _FRAME_ID_RE.match(name):
                raise ConfigError(
                    f"rosbag.frame_ids.{key}",
                    f"must be a ROS frame name (a letter or '_', then letters, digits, '_' or '/'), got {name!r}",
                )
        if len(set(names.values())) != 3:
            raise ConfigError("rosbag.frame_ids", f"the three frames must have distinct names, got {names}")


_TOPIC_RE = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


@dataclass(frozen=True)
class BagTopics:
    """Topic of each message of a frame (defaults: :data:`TOPICS`).

    Attributes
    ----------
    image, fan, pose, tf, points, unit : str
        (``unit``: default the image's topic followed by ``/unit``.)
        ROS topic names (segments of letters, digits and '_', not starting with a digit,
        joined by '/'; a leading '/' makes them absolute). ``tf`` stays ``/tf`` for tf2's
        tools unless a stack remaps it.
    """

    image: str = TOPICS["image"]
    fan: str = TOPICS["fan"]
    pose: str = TOPICS["pose"]
    tf: str = TOPICS["tf"]
    points: str = TOPICS["points"]
    unit: str | None = None

    def __post_init__(self) -> None:
        if self.unit is None:  # beside the image, wherever it is remapped
            object.__setattr__(self, "unit", f"{self.image.rstrip('/')}/unit")
        names = dataclasses.asdict(self)
        for key, name in names.items():
            if not isinstance(name, str) or not _TOPIC_RE.match(name):
                raise ConfigError(f"rosbag.topics.{key}", "must be a ROS topic name (segments of letters, digits "
                                  f"and '_', not starting with a digit, joined by '/'), got {shown(name)}")
        if len(set(names.values())) != len(names):
            raise ConfigError("rosbag.topics", f"every message needs its own topic, got {names}")


#: Keys of a scenario's ``rosbag`` section (and of :func:`bag_naming`).
BAG_NAMING_KEYS = ("frame_ids", "topics")


def bag_naming(doc: Any = None, key: str = "rosbag", **overrides: Mapping[str, str] | None
               ) -> tuple[BagFrameIds, BagTopics]:
    """The frame names and topics of a bag from a mapping such as a scenario's ``rosbag``
    section (``{frame_ids: {world: map}, topics: {image: /oculus/image}}``), with ``overrides``
    (``frame_ids=``, ``topics=``: mappings, e.g. from the command line) replacing its entries
    name by name; what neither sets keeps its default.

    Raises
    ------
    ConfigError
        An unknown key or name (``rosbag.topics.imgae``), a value that is not a ROS name, or
        two frames or topics with one name; the key named is under ``key``.
    """
    if doc is None:
        doc = {}
    if not isinstance(doc, Mapping):
        raise ConfigError(key, f"must be a mapping with {' and/or '.join(BAG_NAMING_KEYS)}, got {shown(doc)}")
    unknown = [k for k in doc if k not in BAG_NAMING_KEYS]
    if unknown:
        raise ConfigError(f"{key}.{unknown[0]}", f"unknown key; allowed: {', '.join(BAG_NAMING_KEYS)}")
    parts: dict[str, dict[str, str]] = {}
    for part, cls in (("frame_ids", BagFrameIds), ("topics", BagTopics)):
        given = doc.get(part) or {}
        if not isinstance(given, Mapping):
            raise ConfigError(f"{key}.{part}", f"must be a mapping of names, got {shown(given)}")
        merged = {**given, **(overrides.get(part) or {})}
        allowed = [f.name for f in dataclasses.fields(cls)]
        bad = [k for k in merged if k not in allowed]
        if bad:
            raise ConfigError(f"{key}.{part}.{bad[0]}", f"unknown name; allowed: {', '.join(allowed)}")
        parts[part] = merged
    try:
        return BagFrameIds(**parts["frame_ids"]), BagTopics(**parts["topics"])
    except ConfigError as exc:  # the dataclasses name rosbag.*; here the caller's key
        raise ConfigError(key + exc.key[len("rosbag"):], exc.detail) from None


# Time ---------------------------------------------------------------------------------------

_NS_PER_S = 1_000_000_000
# builtin_interfaces/Time holds int32 seconds: stamps end before 2038-01-19T03:14:08Z.
_MAX_STAMP_NS = 2**31 * _NS_PER_S

#: The time of a bag's first frame unless the user sets one (``--start-time``, a scenario's
#: ``start_time``). Not zero, which tf2 reads as "the latest transform" and players show as
#: 1970; and fixed rather than the current time, so that the same scenario gives the same bag,
#: byte for byte, whenever it is run.
DEFAULT_START_TIME = "2000-01-01T00:00:00Z"
#: :data:`DEFAULT_START_TIME` in nanoseconds since 1970-01-01T00:00:00Z.
DEFAULT_START_NS = 946_684_800 * _NS_PER_S

_START_TIME_HELP = ("an ISO 8601 time such as 2024-05-01T12:00:00Z (UTC where no offset is given) or a number of "
                    "seconds since 1970-01-01T00:00:00Z, after that instant and before 2038-01-19T03:14:08Z (ROS 2 "
                    "stamps hold int32 seconds)")
# A number of seconds: digits, an optional fraction and exponent (what Decimal reads, but not
# 'NaN', 'Infinity' or '1_000').
_SECONDS_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
# The fraction of the seconds of an ISO 8601 time, which datetime keeps to microseconds only.
_ISO_FRACTION_RE = re.compile(r"(?<=\d)[.,](\d+)(?=(Z|z|[+-]\d{2}(:?\d{2})?)?$)")


def format_stamp(stamp_ns: int) -> str:
    """A stamp as an ISO 8601 UTC time (``2000-01-01T00:00:00Z``; nanoseconds when not zero)."""
    import datetime as dt

    sec, nsec = divmod(int(stamp_ns), _NS_PER_S)
    text = (dt.datetime(1970, 1, 1, tzinfo=dt.timezone.utc) + dt.timedelta(seconds=sec)).strftime("%Y-%m-%dT%H:%M:%S")
    return text + (f".{nsec:09d}".rstrip("0") if nsec else "") + "Z"


def _seconds_ns(seconds: Any) -> int:
    """Seconds (a Decimal) as whole nanoseconds, to the nearest."""
    from decimal import ROUND_HALF_EVEN, Decimal

    return int((Decimal(seconds) * _NS_PER_S).to_integral_value(rounding=ROUND_HALF_EVEN))


def _datetime_ns(value: Any) -> int:
    """A ``datetime`` (naive: UTC, as YAML reads a time without an offset) in nanoseconds."""
    import datetime as dt

    if not isinstance(value, dt.datetime):  # a date alone: its midnight, UTC
        value = dt.datetime(value.year, value.month, value.day)
    if value.tzinfo is None:
        value = value.replace(tzinfo=dt.timezone.utc)
    delta = value - dt.datetime(1970, 1, 1, tzinfo=dt.timezone.utc)
    return (delta.days * 86_400 + delta.seconds) * _NS_PER_S + delta.microseconds * 1000


def parse_start_time(value: Any, key: str = "start_time") -> int:
    """The time of a bag's first frame, in nanoseconds since 1970-01-01T00:00:00Z.

    Parameters
    ----------
    value : str, int, float, datetime.datetime or datetime.date
        An ISO 8601 time (``"2024-05-01T12:00:00Z"``, ``"2024-05-01T14:00:00+02:00"``,
        ``"2024-05-01"``; without an offset it is UTC, as YAML reads it; fractions of a second
        to the nanosecond), or seconds since the epoch (a number, or its text:
        ``"1714564800.5"``). A YAML scenario may hold an unquoted time, which YAML reads as a
        ``datetime``.
    key : str
        What to name in an error: the scenario key or the command-line option.

    Returns
    -------
    int
        Nanoseconds, in ``(0, 2**31 s)``.

    Raises
    ------
    ConfigError
        Not a time, or a time outside ``(1970-01-01T00:00:00Z, 2038-01-19T03:14:08Z)``: zero is
        tf2's "latest", and ROS 2 stamps hold int32 seconds.
    """
    import datetime as dt

    from ..errors import shown

    ns = None
    if isinstance(value, (bool, np.bool_)):
        pass
    elif isinstance(value, (dt.datetime, dt.date)):
        ns = _datetime_ns(value)
    elif isinstance(value, (int, np.integer)):
        ns = int(value) * _NS_PER_S
    elif isinstance(value, (float, np.floating)):
        # repr: the shortest text that reads back as this float, i.e. what the user wrote.
        ns = _seconds_ns(repr(float(value))) if math.isfinite(value) else None
    elif isinstance(value, str) and len(value) <= 100:
        text = value.strip()
        if _SECONDS_RE.match(text):
            from decimal import Decimal

            seconds = Decimal(text)
            # Out of range before any arithmetic: "1e999999999" as an integer would not fit in memory.
            ns = _seconds_ns(seconds) if seconds.adjusted() < 10 else _MAX_STAMP_NS
        else:
            fraction = _ISO_FRACTION_RE.search(text)
            extra_ns = 0
            if fraction and len(fraction.group(1)) <= 9:
                # datetime keeps microseconds: the nanoseconds are added here.
                digits = fraction.group(1).ljust(9, "0")
                extra_ns = int(digits[6:])
                text = text[:fraction.start()] + "." + digits[:6] + text[fraction.end():]
            if text[-1:] in ("Z", "z"):  # Python 3.10's fromisoformat reads no "Z" (3.11 does)
                text = text[:-1] + "+00:00"
            try:
                ns = _datetime_ns(dt.datetime.fromisoformat(text)) + extra_ns
            except ValueError:
                ns = None
    if ns is None:
        raise ConfigError(key, f"must be {_START_TIME_HELP}; got {shown(value)}")
    if not 0 < ns < _MAX_STAMP_NS:
        raise ConfigError(key, f"must be {_START_TIME_HELP}; got {shown(value)}"
                          + (" (a zero stamp means 'the latest transform' to tf2)" if ns == 0 else ""))
    return ns


def frame_stamps(start_ns: int, times_s: Any, key: str = "start_time") -> list[int]:
    """The bag stamps of frames at ``times_s``: the first at ``start_ns``, the others after it
    as the frame times say.

    Parameters
    ----------
    start_ns : int
        The first frame's stamp (:func:`parse_start_time`).
    times_s : sequence of float
        The frames' times, seconds, ascending (a trajectory's: they may start anywhere).
    key : str
        What to name when the last stamp is past what a ROS 2 stamp holds.

    Returns
    -------
    list of int
        ``start_ns + t_k - t_0`` in whole nanoseconds (each time rounded to the nanosecond
        first, so that equal steps give equal steps).

    Raises
    ------
    ConfigError
        The last stamp would be at or after 2038-01-19T03:14:08Z.
    """
    ns = [_seconds_ns(repr(float(t))) for t in times_s]
    if not ns:
        return []
    stamps = [int(start_ns) + t - ns[0] for t in ns]
    if stamps[-1] >= _MAX_STAMP_NS:
        span = (ns[-1] - ns[0]) / _NS_PER_S
        raise ConfigError(key, f"starting at {format_stamp(start_ns)}, the last of {len(ns)} frames ({span:g} s later) "
                          "would be stamped after 2038-01-19T03:14:07Z, the last second a ROS 2 stamp holds (int32 "
                          "seconds); give an earlier start time")
    return stamps


# One frame ----------------------------------------------------------------------------------


def _array(key: str, value: Any, dtype: Any, ndim: int) -> np.ndarray:
    """``value`` as a read-only ``dtype`` array of ``ndim`` dimensions with finite values."""
    a = np.array(value, dtype=dtype)  # a copy: the frame must not change under the writer
    if a.ndim != ndim:
        raise ConfigError(f"bag_frame.{key}", f"must be {ndim}-D, got shape {a.shape}")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise ConfigError(f"bag_frame.{key}", "must be finite numbers")
    a.setflags(write=False)
    return a


def _per_beam(key: str, value: Any, n_beams: int) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"bag_frame.{key}", f"must be an angle in degrees or one per beam, got {value!r}") from None
    if a.ndim == 0:
        a = np.full(n_beams, float(a))
    if a.shape != (n_beams,) or not np.all(np.isfinite(a)) or not np.all(a > 0.0):
        raise ConfigError(f"bag_frame.{key}",
                          f"must be a positive angle in degrees or one per beam ({n_beams}), got shape {a.shape}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class BagFrame:
    """Everything one frame of a bag holds. Validated and copied on construction.

    Attributes
    ----------
    stamp_ns : int
        Transmit time, nanoseconds since 1970-01-01T00:00:00Z, in ``(0, 2**31 s)``: not zero,
        which tf2 reads as "the latest" (:data:`DEFAULT_START_NS` plus the frame's time when
        there is no real time: :func:`frame_stamps`). Every message of the frame carries it,
        as header stamp, TF stamp and bag time.
    pose : Pose
        The sonar's pose in the world frame (sonar-to-world, sonar frame x forward, y left,
        z up).
    polar : (n_range_bins, n_beams) ndarray
        The polar image, row 0 the nearest range bin, column 0 the left-most beam. Any of the
        message's types (uint8 to float64); float32 for a rendered image, uint8 for a device
        model's output.
    range_m : (n_range_bins,) float ndarray
        Range-bin centres, metres, ascending.
    azimuth_deg : (n_beams,) float ndarray
        Beam centres, DEGREES, positive to the sonar's left, left-most first (descending).
    tx_beamwidth_deg, rx_beamwidth_deg : float or (n_beams,) float ndarray
        Transmit and receive beamwidths, degrees (positive): one value for all beams or one
        per beam. Written in radians, one per beam.
    frequency_hz : float
        Carrier frequency, Hz; 0 when unknown.
    sound_speed_m_s : float
        Sound speed, m/s (> 0).
    fan : (height, width) uint8 or float32 ndarray, optional
        The fan image (apex at the bottom centre, far range on row 0, the sonar's left on the
        left), written on ``/sonar/fan``.
    points_world : (n, 3) float32 ndarray, optional
        Ground-truth points in view, world frame, metres. Given with ``points_object``.
    points_object : (n,) int32 ndarray, optional
        Object id of each point (the NPZ's ``points_object``).
    unit : str
        What ``polar``'s values are (:mod:`sonarsim.image.units`), written on the unit topic
        with the first frame and whenever it changes; empty: not written.
    """

    stamp_ns: int
    pose: Pose
    polar: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    tx_beamwidth_deg: Any
    rx_beamwidth_deg: Any
    frequency_hz: float
    sound_speed_m_s: float
    fan: np.ndarray | None = None
    points_world: np.ndarray | None = None
    points_object: np.ndarray | None = None
    unit: str = ""

    def __post_init__(self) -> None:
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731 - frozen
        if not isinstance(self.unit, str) or len(self.unit) > 64 or not self.unit.isprintable():
            raise ConfigError("bag_frame.unit", f"must be a short printable string (a unit's name), got {shown(self.unit)}")
        if isinstance(self.stamp_ns, (bool, np.bool_)) or not isinstance(self.stamp_ns, (int, np.integer)) \
                or not 0 < int(self.stamp_ns) < _MAX_STAMP_NS:
            # Zero is refused: tf2 reads a zero stamp as "the latest transform", not a time.
            raise ConfigError("bag_frame.stamp_ns",
                              f"must be an integer number of nanoseconds since 1970 in (0, 2**31 s), e.g. "
                              f"DEFAULT_START_NS ({DEFAULT_START_TIME}) plus the frame's time; got {self.stamp_ns!r}")
        put("stamp_ns", int(self.stamp_ns))
        if not isinstance(self.pose, Pose):
            raise ConfigError("bag_frame.pose", f"must be a sonarsim Pose, got {type(self.pose).__name__}")
        polar = np.asarray(self.polar)
        if polar.dtype not in _SONAR_DTYPES:
            raise ConfigError("bag_frame.polar",
                              f"dtype must be one of {sorted(str(d) for d in _SONAR_DTYPES)}, got {polar.dtype}")
        polar = _array("polar", polar, polar.dtype.newbyteorder("<"), 2)
        n_ranges, n_beams = polar.shape
        if n_ranges < 1 or n_beams < 1:
            raise ConfigError("bag_frame.polar", f"must hold at least one cell, got shape {polar.shape}")
        put("polar", polar)
        rng = _array("range_m", self.range_m, np.float64, 1)
        if rng.shape != (n_ranges,) or not np.all(np.diff(rng) > 0) or rng[0] < 0:
            raise ConfigError("bag_frame.range_m",
                              f"must be {n_ranges} ascending ranges >= 0 (one per row of polar), got shape {rng.shape}")
        put("range_m", rng)
        az = _array("azimuth_deg", self.azimuth_deg, np.float64, 1)
        if az.shape != (n_beams,) or not np.all(np.diff(az) < 0) or not np.all(np.abs(az) < 180.0):
            raise ConfigError("bag_frame.azimuth_deg",
                              f"must be {n_beams} descending angles in (-180, 180) degrees, left-most beam first "
                              f"(one per column of polar), got shape {az.shape}")
        put("azimuth_deg", az)
        put("tx_beamwidth_deg", _per_beam("tx_beamwidth_deg", self.tx_beamwidth_deg, n_beams))
        put("rx_beamwidth_deg", _per_beam("rx_beamwidth_deg", self.rx_beamwidth_deg, n_beams))
        f = float(self.frequency_hz)
        if not (math.isfinite(f) and f >= 0.0):
            raise ConfigError("bag_frame.frequency_hz", f"must be >= 0 Hz (0: unknown), got {self.frequency_hz!r}")
        put("frequency_hz", f)
        c = float(self.sound_speed_m_s)
        if not (math.isfinite(c) and c > 0.0):
            raise ConfigError("bag_frame.sound_speed_m_s", f"must be > 0 m/s, got {self.sound_speed_m_s!r}")
        put("sound_speed_m_s", c)
        if self.fan is not None:
            fan = np.asarray(self.fan)
            if fan.dtype not in _FAN_ENCODINGS:
                raise ConfigError("bag_frame.fan", f"dtype must be uint8 or float32, got {fan.dtype}")
            put("fan", _array("fan", fan, fan.dtype.newbyteorder("<"), 2))
        if (self.points_world is None) != (self.points_object is None):
            raise ConfigError("bag_frame.points_object", "give points_world and points_object together, or neither")
        if self.points_world is not None:
            pts = _array("points_world", self.points_world, np.float32, 2)
            obj = np.asarray(self.points_object)
            if obj.dtype.kind not in "iu" or (obj.size and (obj.min() < -2**31 or obj.max() >= 2**31)):
                raise ConfigError("bag_frame.points_object", f"must be int32 object ids, got dtype {obj.dtype}")
            obj = _array("points_object", obj, np.int32, 1)
            if pts.shape[1:] != (3,) or obj.shape != (pts.shape[0],):
                raise ConfigError("bag_frame.points_world",
                                  f"must be (n, 3) with points_object (n,), got {pts.shape} and {obj.shape}")
            put("points_world", pts)
            put("points_object", obj)

    @property
    def n_beams(self) -> int:
        """Number of beams (columns of :attr:`polar`)."""
        return int(self.polar.shape[1])


def beam_directions(azimuth_deg: np.ndarray) -> np.ndarray:
    """Beam unit vectors in the ``ProjectedSonarImage`` frame (Z forward, X up, Y right).

    Parameters
    ----------
    azimuth_deg : (n_beams,) array_like, degrees
        Beam azimuths, positive to the sonar's left.

    Returns
    -------
    (n_beams, 3) float64 ndarray
        ``(0, -sin theta, cos theta)`` per beam: a beam to the left has y < 0.
    """
    theta = np.radians(np.asarray(azimuth_deg, dtype=np.float64))
    return np.stack([np.zeros_like(theta), -np.sin(theta), np.cos(theta)], axis=-1)


def device_polar(image: SonarImage) -> np.ndarray:
    """The polar image in the type the device sends: a sensor model's 8- or 16-bit output (whole
    counts, held as float32 by the renderer) as uint8 or uint16, so that a bag carries
    ``DTYPE_UINT8`` data as the real device's driver would; anything else (a render's intensity,
    an expected output with fractional counts) as it is."""
    polar = np.asarray(image.polar)
    sensor = image.config.get("sensor") if isinstance(image.config, Mapping) else None
    dtype = ((sensor.get("output") or {}).get("dtype") if isinstance(sensor, Mapping) else None)
    if dtype not in ("uint8", "uint16") or polar.dtype.kind != "f":
        return polar
    top = np.iinfo(dtype).max
    with np.errstate(invalid="ignore"):
        whole = bool(np.all((polar >= 0) & (polar <= top) & (polar == np.round(polar))))
    return polar.astype(dtype) if whole else polar


def frame_from_image(
    image: SonarImage,
    stamp_ns: int,
    *,
    fan: bool | np.ndarray | None = None,
    points_world: np.ndarray | None = None,
    points_object: np.ndarray | None = None,
    frequency_hz: float | None = None,
    sound_speed_m_s: float | None = None,
) -> BagFrame:
    """A :class:`BagFrame` of a rendered :class:`~sonarsim.image.result.SonarImage`.

    Parameters
    ----------
    image : SonarImage
        Must carry its pose (renders do; real recordings do not).
    stamp_ns : int
        Transmit time, nanoseconds since 1970 (> 0; see :class:`BagFrame`).
    fan : bool or (height, width) ndarray, optional
        ``True``: the image's default fan (:meth:`SonarImage.fan`: float32, ``32FC1``; an
        8-bit device's in its counts, ``mono8``); an array: that fan image.
    points_world, points_object : ndarray, optional
        Ground-truth points, (n, 3) float32 world frame and (n,) int32 object ids.
    frequency_hz : float, optional
        Default: the sensor section's ``frequency_khz``, else the sonar's, else 0 (unknown).
    sound_speed_m_s : float, optional
        Default: the sensor section's ``sound_speed_m_s``, else the sensor model's default.

    Returns
    -------
    BagFrame
        Transmit beamwidth = the sonar's elevation aperture, receive beamwidth = each beam's
        azimuth width (:meth:`SonarConfig.effective_beam_width_deg`).
    """
    from ..config.sensor import SensorSpec

    if image.pose is None:
        raise SonarsimError("a bag frame needs the sonar's pose; this image has none (a real recording?)")
    sensor = image.config.get("sensor") if isinstance(image.config, Mapping) else None
    sensor = sensor if isinstance(sensor, Mapping) else {}
    if frequency_hz is None:
        khz = sensor.get("frequency_khz") or image.sonar.frequency_khz
        frequency_hz = 1000.0 * float(khz) if khz else 0.0
    if sound_speed_m_s is None:
        sound_speed_m_s = float(sensor.get("sound_speed_m_s") or SensorSpec().sound_speed_m_s)
    polar = device_polar(image)
    fan_image = None if fan is False else fan
    if fan is True:
        default = image.fan()
        fan_image = default.image
        if polar.dtype == np.uint8:  # an 8-bit device's fan in its counts (mono8), as its PNG
            from ..image.levels import default_fan_levels

            fan_image = default_fan_levels(image)
    return BagFrame(
        stamp_ns=stamp_ns,
        pose=image.pose,
        polar=polar,
        range_m=image.range_m,
        azimuth_deg=image.azimuth_deg,
        tx_beamwidth_deg=image.sonar.elevation_fov_deg,
        rx_beamwidth_deg=image.sonar.effective_beam_width_deg(),
        frequency_hz=frequency_hz,
        sound_speed_m_s=sound_speed_m_s,
        fan=fan_image,
        points_world=points_world,
        points_object=points_object,
        unit=image.unit.name,
    )


# The writer ---------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _import_rosbags() -> tuple[Any, Any, Any]:
    """``(Writer, StoragePlugin, typestore)``, or a SonarsimError naming the extra.

    Cached: building the typestore compiles the message classes (tens of milliseconds), and
    writers only read it.
    """
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError as exc:
        raise SonarsimError(f"writing ROS 2 bags needs the 'rosbags' library ({exc}); {install_hint('ros')}") from None
    # Humble's definitions of the std/geometry/sensor/tf2 messages, which later distributions
    # kept unchanged; the marine_acoustic_msgs are not in any store and are added here.
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in _MSG_DEFS.items():
        types.update(get_types_from_msg(text, name))
    typestore.register(types)
    return Writer, StoragePlugin, typestore


class FrameMessages:
    """The ROS 2 messages of a :class:`BagFrame`: one home for what they hold, whether they go
    into a bag (:class:`BagWriter`) or onto live topics (:mod:`sonarsim.live`).

    Parameters
    ----------
    typestore : rosbags typestore
        Where the message classes come from (:func:`_import_rosbags`'s).
    frame_ids : BagFrameIds, optional
    """

    #: The message types the frames' messages are built of.
    TYPES = ("builtin_interfaces/msg/Time", "std_msgs/msg/Header", "geometry_msgs/msg/Vector3",
             "geometry_msgs/msg/Point", "geometry_msgs/msg/Quaternion", "geometry_msgs/msg/Pose",
             "geometry_msgs/msg/Transform", "geometry_msgs/msg/TransformStamped",
             "sensor_msgs/msg/PointField", "marine_acoustic_msgs/msg/PingInfo",
             "marine_acoustic_msgs/msg/SonarImageData", *_MSGTYPES.values())

    def __init__(self, typestore: Any, frame_ids: BagFrameIds | None = None) -> None:
        self.frame_ids = frame_ids if frame_ids is not None else BagFrameIds()
        self._types: dict[str, type] = {name: typestore.types[name] for name in self.TYPES}

    def frame_messages(self, frame: BagFrame, last_unit: str = "", tf: str = "both") -> list[tuple[str, Any]]:
        """``(key, message)`` of a frame, keys of :data:`TOPICS`: the image, the fan (where the
        frame has one), the pose, the TF (``tf``: :meth:`_tf_msg`'s parts), the points (where
        it has them) and the unit (where it differs from ``last_unit``)."""
        messages = [("image", self._image_msg(frame)), ("pose", self._pose_msg(frame)), ("tf", self._tf_msg(frame, tf))]
        if frame.fan is not None:
            messages.insert(1, ("fan", self._fan_msg(frame)))
        if frame.points_world is not None:
            messages.append(("points", self._points_msg(frame)))
        if frame.unit and frame.unit != last_unit:
            messages.append(("unit", self._types["std_msgs/msg/String"](data=frame.unit)))
        return messages

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        t = self._types
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                        frame_id=frame_id)

    def _image_msg(self, frame: BagFrame) -> Any:
        t = self._types
        vec = t["geometry_msgs/msg/Vector3"]
        dirs = beam_directions(frame.azimuth_deg)
        ping = t["marine_acoustic_msgs/msg/PingInfo"](
            frequency=frame.frequency_hz,
            sound_speed=frame.sound_speed_m_s,
            tx_beamwidths=np.radians(frame.tx_beamwidth_deg).astype(np.float32),
            rx_beamwidths=np.radians(frame.rx_beamwidth_deg).astype(np.float32),
        )
        # C order of (n_range_bins, n_beams) is the message's range-major order; frame.polar
        # is little-endian already (BagFrame), so this is a view, not a copy.
        data = np.ascontiguousarray(frame.polar).reshape(-1).view(np.uint8)
        image = t["marine_acoustic_msgs/msg/SonarImageData"](
            is_bigendian=False, dtype=_SONAR_DTYPES[frame.polar.dtype.newbyteorder("=")],
            beam_count=frame.n_beams, data=data,
        )
        return t["marine_acoustic_msgs/msg/ProjectedSonarImage"](
            header=self._header(frame.stamp_ns, self.frame_ids.image),
            ping_info=ping,
            beam_directions=[vec(x=float(x), y=float(y), z=float(z)) for x, y, z in dirs],
            ranges=frame.range_m.astype(np.float32),
            image=image,
        )

    def _fan_msg(self, frame: BagFrame) -> Any:
        fan = np.ascontiguousarray(frame.fan)
        height, width = fan.shape
        return self._types["sensor_msgs/msg/Image"](
            header=self._header(frame.stamp_ns, self.frame_ids.sonar),
            height=height, width=width,
            encoding=_FAN_ENCODINGS[fan.dtype.newbyteorder("=")],
            is_bigendian=0, step=width * fan.dtype.itemsize,
            data=fan.reshape(-1).view(np.uint8),
        )

    def _pose_parts(self, frame: BagFrame) -> tuple[Any, Any]:
        t = self._types
        x, y, z = frame.pose.position_m
        qx, qy, qz, qw = frame.pose.quat_xyzw
        return (t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))

    def _pose_msg(self, frame: BagFrame) -> Any:
        t = self._types
        position, rotation = self._pose_parts(frame)
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=position.x, y=position.y, z=position.z), orientation=rotation)
        return t["geometry_msgs/msg/PoseStamped"](header=self._header(frame.stamp_ns, self.frame_ids.world), pose=pose)

    def tf_message(self, frame: BagFrame, parts: str = "both") -> Any:
        """:meth:`_tf_msg`: ``/tf``'s message of a frame, or one of its two transforms."""
        return self._tf_msg(frame, parts)

    def _tf_msg(self, frame: BagFrame, parts: str = "both") -> Any:
        """``/tf``'s message: world -> sonar (the pose) and sonar -> sonar_image (constant);
        ``parts`` ``"pose"`` or ``"image"`` gives one of them (live topics send the constant one
        on ``/tf_static``)."""
        t = self._types
        stamped, transform = t["geometry_msgs/msg/TransformStamped"], t["geometry_msgs/msg/Transform"]
        position, rotation = self._pose_parts(frame)
        qx, qy, qz, qw = SONAR_TO_IMAGE_QUAT_XYZW
        pose = stamped(header=self._header(frame.stamp_ns, self.frame_ids.world), child_frame_id=self.frame_ids.sonar,
                       transform=transform(translation=position, rotation=rotation))
        image = stamped(header=self._header(frame.stamp_ns, self.frame_ids.sonar), child_frame_id=self.frame_ids.image,
                        transform=transform(translation=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                            rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))
        chosen = {"both": [pose, image], "pose": [pose], "image": [image]}[parts]
        return t["tf2_msgs/msg/TFMessage"](transforms=chosen)

    def objects_tf(self, stamp_ns: int, poses: Mapping[str, Any]) -> Any:
        """``/tf``'s message of the objects that move: world -> each object's name (its pose,
        object-to-world), the ground truth a consumer compares its tracks with."""
        t = self._types
        transforms = []
        for name, pose in poses.items():
            x, y, z = pose.position_m
            qx, qy, qz, qw = pose.quat_xyzw
            transforms.append(t["geometry_msgs/msg/TransformStamped"](
                header=self._header(stamp_ns, self.frame_ids.world), child_frame_id=str(name),
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                    rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))))
        return t["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def _points_msg(self, frame: BagFrame) -> Any:
        t = self._types
        n = frame.points_world.shape[0]
        cloud = np.empty(n, dtype=_POINT_DTYPE)
        cloud["x"], cloud["y"], cloud["z"] = frame.points_world.T
        cloud["object"] = frame.points_object
        field = t["sensor_msgs/msg/PointField"]
        fields = [field(name=name, offset=_POINT_DTYPE.fields[name][1],
                        datatype=_POINTFIELD_INT32 if name == "object" else _POINTFIELD_FLOAT32, count=1)
                  for name in _POINT_DTYPE.names]
        return t["sensor_msgs/msg/PointCloud2"](
            header=self._header(frame.stamp_ns, self.frame_ids.world),
            height=1, width=n, fields=fields, is_bigendian=False,
            point_step=_POINT_DTYPE.itemsize, row_step=_POINT_DTYPE.itemsize * n,
            data=cloud.view(np.uint8), is_dense=True,  # BagFrame admits only finite points
        )


class BagWriter(FrameMessages):
    """Write frames to a ROS 2 bag (a folder), atomically. Use as a context manager.

    Parameters
    ----------
    path : str or os.PathLike
        The bag folder to create (e.g. ``DIR/rosbag``); it must not exist, its parent must.
    storage : {"mcap", "sqlite3"}
        Storage plugin: one ``.mcap`` or ``.db3`` file inside the folder, with
        ``metadata.yaml`` (rosbag2 format version 9).
    frame_ids : BagFrameIds, optional
        Names of the world, sonar and image frames.
    topics : BagTopics, optional
        Topic of each message (default :data:`TOPICS`).

    Examples
    --------
    >>> stamps = frame_stamps(DEFAULT_START_NS, [0.0, 0.1, 0.2])   # or parse_start_time("2024-05-01T12:00Z")
    >>> with BagWriter(out / "rosbag", storage="mcap") as bag:   # doctest: +SKIP
    ...     for stamp, image in zip(stamps, images):
    ...         bag.write_frame(frame_from_image(image, stamp_ns=stamp, fan=True))

    Notes
    -----
    Frames are written in call order; give them ascending stamps. ``metadata.yaml``'s
    ``starting_time`` and ``duration`` and the MCAP summary's statistics are the first and last
    stamps written. Nothing appears at
    ``path`` until the ``with`` block (or :meth:`close`) ends without error; on error, or
    :meth:`abort`, the partial bag is deleted.
    """

    def __init__(self, path: str | os.PathLike, storage: str = "mcap", frame_ids: BagFrameIds | None = None,
                 topics: BagTopics | None = None) -> None:
        if storage not in BAG_STORAGES:
            raise ConfigError("rosbag", f"storage must be one of {', '.join(BAG_STORAGES)}, got {storage!r}")
        self.path = Path(path)
        self.storage = storage
        self.frame_ids = frame_ids if frame_ids is not None else BagFrameIds()
        if not isinstance(self.frame_ids, BagFrameIds):
            raise ConfigError("rosbag.frame_ids", f"must be a BagFrameIds, got {type(frame_ids).__name__}")
        self.topics = topics if topics is not None else BagTopics()
        if not isinstance(self.topics, BagTopics):
            raise ConfigError("rosbag.topics", f"must be a BagTopics, got {type(topics).__name__}")
        self.frames_written = 0
        self._writer: Any = None
        self._tmp_dir: Path | None = None
        self._connections: dict[str, Any] = {}
        self._types: dict[str, type] = {}
        self._typestore: Any = None
        self._last_stamp = -1
        self._last_unit = ""

    # Life cycle ------------------------------------------------------------------------

    def open(self) -> BagWriter:
        """Create the temporary bag and its connections (done by ``with``)."""
        if self._writer is not None:
            raise SonarsimError(f"{self.path}: the bag is already open")
        writer_cls, plugins, typestore = _import_rosbags()
        if self.path.exists() or self.path.is_symlink():
            raise SonarsimError(f"{self.path}: exists already; a bag is written only to a new folder "
                                "(remove it or choose another)")
        parent = self.path.parent
        if not parent.is_dir():
            raise SonarsimError(f"{parent}: no such folder (the bag's folder is created, not its parent)")
        try:
            tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(self.path.name), suffix=".tmp", dir=parent))
        except OSError as exc:
            raise SonarsimError(f"{self.path}: cannot write here: {exc.strerror or exc}") from None
        self._tmp_dir = tmp
        try:
            plugin = plugins.MCAP if self.storage == "mcap" else plugins.SQLITE3
            # Inside the temporary folder under the final name: the storage file is named
            # after its folder (rosbag/rosbag.mcap), and metadata.yaml lists it by that name.
            writer = writer_cls(tmp / self.path.name, version=9, storage_plugin=plugin)
            writer.open()
            self._writer = writer
            self._typestore = typestore
            for name in FrameMessages.TYPES:
                self._types[name] = typestore.types[name]
        except BaseException:
            self._discard()
            raise
        return self

    def close(self) -> Path:
        """Finish the bag and move it to :attr:`path` (done by ``with`` on success).

        Returns
        -------
        pathlib.Path
            The bag folder.
        """
        if self._writer is None:
            raise SonarsimError(f"{self.path}: the bag is not open")
        writer, self._writer = self._writer, None
        try:
            writer.close()
            os.rename(self._tmp_dir / self.path.name, self.path)
        except BaseException as exc:
            self._discard()
            if isinstance(exc, OSError):
                raise SonarsimError(f"{self.path}: cannot finish the bag: {exc.strerror or exc}") from None
            raise
        shutil.rmtree(self._tmp_dir, ignore_errors=True)
        self._tmp_dir = None
        return self.path

    def abort(self) -> None:
        """Drop the partial bag; nothing is left at :attr:`path` or in the temporary folder."""
        self._discard()

    def _discard(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.abort()
            except Exception:  # noqa: BLE001 - the folder goes anyway
                pass
        if self._tmp_dir is not None:
            shutil.rmtree(self._tmp_dir, ignore_errors=True)
            self._tmp_dir = None

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:  # also KeyboardInterrupt and the CLI's SIGTERM exception: no partial bag
            self._discard()

    # Messages --------------------------------------------------------------------------

    def write_frame(self, frame: BagFrame) -> None:
        """Write one frame's messages (image, fan, pose, TF, points), all stamped ``frame.stamp_ns``.

        Parameters
        ----------
        frame : BagFrame
            Its stamp must not be earlier than the previous frame's.
        """
        if self._writer is None:
            raise SonarsimError(f"{self.path}: the bag is not open (use 'with BagWriter(...) as bag')")
        if not isinstance(frame, BagFrame):
            raise ConfigError("bag_frame", f"must be a BagFrame, got {type(frame).__name__}")
        if frame.stamp_ns < self._last_stamp:
            raise ConfigError("bag_frame.stamp_ns",
                              f"frames must come in time order: {frame.stamp_ns} after {self._last_stamp}")
        messages = self.frame_messages(frame, self._last_unit)
        try:
            for key, msg in messages:
                if key not in self._connections:
                    # Added at first use, so that a bag without fans or points lists no such topic.
                    self._connections[key] = self._writer.add_connection(getattr(self.topics, key), _MSGTYPES[key],
                                                                         typestore=self._typestore)
                self._writer.write(self._connections[key], frame.stamp_ns,
                                   self._typestore.serialize_cdr(msg, _MSGTYPES[key]))
        except OSError as exc:  # a full disk: the caller's with block discards the bag
            raise SonarsimError(f"{self.path}: cannot write the bag: {exc.strerror or exc}") from None
        self._last_stamp = frame.stamp_ns
        self._last_unit = frame.unit or self._last_unit
        self.frames_written += 1

    def write_cdr(self, topic: str, ros_type: str, stamp_ns: int, cdr: bytes) -> None:
        """Write one message already serialised (a recorder's: the CDR as it arrived).

        Parameters
        ----------
        topic : str
            Its topic; the first message of a topic adds its connection, of ``ros_type``.
        ros_type : str
            ``pkg/msg/Name``, a type of the bags' typestore
            (:func:`~sonarsim.io.rosbag_instruments.instrument_typestore`).
        stamp_ns : int
            The bag's time for it (a recorder's: when it arrived), nanoseconds since the epoch.
        cdr : bytes
            The serialised message, its encapsulation header first.
        """
        if self._writer is None:
            raise SonarsimError(f"{self.path}: the bag is not open (use 'with BagWriter(...) as bag')")
        key = f"cdr:{topic}"
        if key not in self._connections:
            if ros_type not in self._typestore.fielddefs:
                raise ConfigError("rosbag", f"{topic}: {ros_type} is not a message sonarsim knows")
            self._connections[key] = self._writer.add_connection(topic, ros_type, typestore=self._typestore)
        elif self._connections[key].msgtype != ros_type:
            raise ConfigError("rosbag", f"{topic} carries {self._connections[key].msgtype}, not {ros_type}")
        try:
            self._writer.write(self._connections[key], int(stamp_ns), bytes(cdr))
        except OSError as exc:
            raise SonarsimError(f"{self.path}: cannot write the bag: {exc.strerror or exc}") from None


# Leftovers of killed runs -------------------------------------------------------------------

_TEMP_DIR_RE = re.compile(r"^\.(?P<name>.+)" + re.escape(TEMP_MARK) + r"(?P<pid>[0-9]+)-[A-Za-z0-9_]+\.tmp$")


def remove_abandoned_bags(folder: str | os.PathLike) -> list[str]:
    """Remove the temporary bag folders that killed :class:`BagWriter` runs left in ``folder``.

    A folder counts as abandoned when its name is ``.NAME.sonarsim-PID-XXXX.tmp`` and no process
    ``PID`` exists (bags being written by live processes are left alone).

    Parameters
    ----------
    folder : str or os.PathLike
        Where the bags are written (the parent of ``DIR/rosbag``); a missing folder holds none.

    Returns
    -------
    list of str
        The names of the removed folders, sorted.
    """
    from .output import _pid_alive  # the same liveness test as atomic_write's leftovers

    try:
        entries = list(os.scandir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return []
    removed = []
    for entry in entries:
        match = _TEMP_DIR_RE.match(entry.name)
        if not match or not entry.is_dir(follow_symlinks=False) or _pid_alive(int(match["pid"])):
            continue
        shutil.rmtree(entry.path, ignore_errors=True)
        removed.append(entry.name)
    return sorted(removed)

