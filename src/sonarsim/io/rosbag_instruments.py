"""ROS 2 bags of every instrument's films (side-scan, scanning, single-beam, multibeam, FLS),
written with ``rosbags`` through :class:`~sonarsim.io.rosbag.BagWriter` (atomic: a temporary
folder renamed at the end).

:func:`write_instrument_bag` takes the films of a scene's instruments (what
:func:`sonarsim.instruments.render_pings` returns, by instrument name) and writes, per instrument
``NAME`` (topics ``/NAME/...``, frames ``NAME`` and ``NAME_image``):

=================== ============================================= ===============================
instrument (film)    topic: type                                   one message per
=================== ============================================= ===============================
sidescan (Waterfall) ``/NAME/raw``: RawSonarImage, 2 beams          ping (port beam 0, starboard 1)
scanning (ScanImage) ``/NAME/raw``: RawSonarImage, 1 beam           step, with its head angle
singlebeam (Envelope) ``/NAME/raw``: RawSonarImage, 1 beam;          ping
                     ``/NAME/range``: sensor_msgs/Range (bottom)
multibeam (Soundings) ``/NAME/detections``: SonarDetections;         ping
                     ``/NAME/points``: PointCloud2 (vehicle frame);
                     ``/NAME/water_column``: ProjectedSonarImage
fls (SonarImage list) ``/NAME/image``: ProjectedSonarImage           ping
every instrument     ``/NAME/unit``: std_msgs/String                the first ping: what the film's
                                                                   values are (the film's
                                                                   ``unit_name``,
                                                                   :mod:`sonarsim.image.units`)
=================== ============================================= ===============================

and for the vehicle ``/tf`` (``world -> vehicle`` at every stamp a ping has) and ``/tf_static``
(once, reliable and transient-local as tf2's static broadcaster offers it: ``vehicle -> NAME``,
the mount, and ``NAME -> NAME_image``; a single-beam adds ``NAME -> NAME_beam``, the x-along-
the-beam frame ``sensor_msgs/Range`` needs). Names of the world and vehicle frames:
:class:`InstrumentBagNames`.

Frames
------
``NAME``
    The instrument's mount: sonarsim's vehicle convention (x forward, y port, z up); its pose
    in the vehicle is the scene's ``mount``.
``NAME_image``
    The frame of the ``marine_acoustic_msgs`` messages: Z along the instrument's reference axis,
    X "up" across the fan plane, Y = Z x X. For instruments that look DOWN (side-scan,
    multibeam, single-beam) Z is the mount's -z, X its +x, Y its -y (starboard): forward,
    starboard, down, the NED-like frame the messages are defined in for profilers (the mount
    turned 180 deg about x). For those that look FORWARD (FLS, scanning) Z is the mount's +x,
    X its +z, Y its -y, as in :mod:`sonarsim.io.rosbag` (:data:`~sonarsim.io.rosbag.SONAR_TO_IMAGE_QUAT_XYZW`).
    A beam with transmit (out-of-fan) angle ``tx`` and receive (in-fan) angle ``rx`` has the
    direction ``(sin tx, cos tx sin rx, cos tx cos rx)``: ``rx > 0`` towards +Y (starboard for a
    down-looking sonar, as ``SonarDetections`` defines it; to the right of a forward-looking one).

Angles written
--------------
* side-scan: the two beams' ``rx_angles`` are ``-(90 - depression)`` (port) and ``+(90 -
  depression)`` (starboard), ascending as the reference water-column viewer
  (k2oceanic/acoustic_msgs_tools) interpolates them; ``tx_angles`` 0.
* scanning: ``rx_angles = [-head angle]`` wrapped to (-180, 180] (the head angle is > 0 to port,
  REP-103 yaw; ``rx`` > 0 is to the right); ``tx_angles = [-tilt]`` (a tilt down is towards -X).
* single-beam: ``rx = tx = 0`` (straight down).
* multibeam: ``rx_angles = -angle_deg`` (``Soundings.angle_deg`` is > 0 to port), in radians;
  the water column's beam directions are :func:`~sonarsim.io.rosbag.beam_directions` of
  ``angle_deg`` (y < 0 to port), the FLS's convention in this frame.

Side-scan: one message per ping with both sides, not one per side. Port and starboard are one
transmit (one stamp, one ping number): a consumer gets them together without pairing stamps; the
two lines share their sample rate, window and count, which is what one ``RawSonarImage`` (one
``samples_per_beam``, one ``sample_rate``) can hold; and the reference viewer draws them as the
across-track section they are (port at ``-(90 - depression)``, starboard at ``+(90 -
depression)``).

Samples
-------
``RawSonarImage.image.data`` is sample-major (``index = row * beam_count + beam``, row 0 the
nearest sample), as the reference viewer reads it and as ``ProjectedSonarImage`` is;
little-endian float32 (``DTYPE_FLOAT32``). ``sample_rate = c / (2 dr)`` with the ping's sound
speed ``c`` and the film's sample spacing ``dr``: row ``r`` starts at range
``(sample0 + r) c / (2 sample_rate) = (sample0 + r) dr``. ``sample0`` = ``range_min_m / dr`` to the nearest whole sample (halves up):
exact where the window starts on a whole sample (every preset: ``range_min_m = 0``); otherwise
the written start is off by less than half a sample, and the exact windows are in the bag's
``custom_data`` (``metadata.yaml``: ``sonarsim.instruments``, JSON per instrument: type, window,
samples, frames, topics). ``tx_delays`` are 0 (one transmit). ``ping_info``: the carrier in Hz,
the ping's sound speed, and per beam the -3 dB widths in radians, transmit = across the fan plane
(side-scan: along track; scanning and FLS: vertical), receive = within it.

Multibeam: ``two_way_travel_times`` as the film has them (seconds), NaN where a beam found no
bottom, that beam flagged ``DETECT_BAD_SONAR`` (1; 0 = good); ``intensities`` in the film's
units; the point cloud holds the beams with a detection, ``x, y, z, intensity`` (float32), in the
VEHICLE frame: the straight-ray sounding ``(0, r sin a, -r cos a)`` in the head (mount) frame
(:meth:`~sonarsim.image.films.Soundings.head_points`) moved by the mount.

Single-beam ``Range``: ``range`` = the detected bottom, ``+inf`` where none (REP 117: no
return), ``field_of_view`` = the -3 dB beam width, the window as ``min_range``/``max_range``,
``radiation_type`` ULTRASOUND.

Time: a ping's stamp is ``start_ns`` plus its time minus the earliest first-ping time of all the
films (the films' ``geometry.time_s``; an FLS's from ``times_s``), to the nanosecond; every
message of that ping and its ``world -> vehicle`` transform carry it. Messages are written in
time order across instruments.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.transforms import Pose
from ..errors import ConfigError, SonarsimError, shown
from . import rosbag as rb

__all__ = [
    "DOWN_TO_IMAGE_QUAT_XYZW",
    "INSTRUMENT_MSGTYPES",
    "InstrumentBagNames",
    "InstrumentBagWriter",
    "InstrumentMessages",
    "instrument_typestore",
    "beam_unit_vectors",
    "instrument_topics",
    "recording_poses",
    "write_instrument_bag",
]

#: Rotation of a down-looking instrument's message frame relative to its mount: 180 deg about x
#: (Z = the mount's -z, X = its +x, Y = its -y).
DOWN_TO_IMAGE_QUAT_XYZW = (1.0, 0.0, 0.0, 0.0)
# The single-beam's beam frame (x along the beam, straight down) relative to its mount: pitch
# +90 deg (REP-103: > 0 turns x down), the channel's own rotation.
_BEAM_QUAT_XYZW = (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))

# Message definitions written from the field lists of marine_acoustic_msgs 2.0 (BSD-3,
# apl-ocean-engineering/marine_msgs); the fields are what matter to the wire format and the
# type hash, so these carry our own comments. PingInfo and SonarImageData are rosbag.py's.
_MSG_DEFS: dict[str, str] = {
    "marine_acoustic_msgs/msg/RawSonarImage": """
# Beamformed samples against time, one column per beam.
std_msgs/Header header
PingInfo ping_info
float32 sample_rate        # Hz: rows per second of two-way time
uint32 samples_per_beam    # rows
uint32 sample0             # sample number of row 0 (rows before the window are not sent)
float32[] tx_delays        # s, per beam
float32[] tx_angles        # rad, per beam, out of the fan plane
float32[] rx_angles        # rad, per beam, within the fan plane
SonarImageData image       # row-major: index = row * beam_count + beam
""",
    "marine_acoustic_msgs/msg/DetectionFlag": """
# Quality of one beam's detection (a bit mask; 0 is good).
uint8 DETECT_OK=0
uint8 DETECT_BAD_SONAR=1
uint8 DETECT_BAD_FILTER=2
uint8 DETECT_BAD_USER=4
uint8 flag
""",
    "marine_acoustic_msgs/msg/SonarDetections": """
# One multibeam ping's bottom detections, one entry per beam.
std_msgs/Header header
PingInfo ping_info
DetectionFlag[] flags
float32[] two_way_travel_times   # s
float32[] tx_delays              # s
float32[] intensities
float32[] tx_angles              # rad, along track, + forward
float32[] rx_angles              # rad, across track, + starboard
""",
}

#: Message type of each per-instrument topic suffix.
INSTRUMENT_MSGTYPES: Mapping[str, str] = {
    "raw": "marine_acoustic_msgs/msg/RawSonarImage",
    "range": "sensor_msgs/msg/Range",
    "detections": "marine_acoustic_msgs/msg/SonarDetections",
    "points": "sensor_msgs/msg/PointCloud2",
    "water_column": "marine_acoustic_msgs/msg/ProjectedSonarImage",
    "image": "marine_acoustic_msgs/msg/ProjectedSonarImage",
    "unit": "std_msgs/msg/String",
}
# (every instrument's ``unit``: what its samples, intensities or images are, once with its first ping)
_TOPICS_OF_TYPE = {
    "sidescan": ("raw", "unit"), "scanning": ("raw", "unit"), "singlebeam": ("raw", "range", "unit"),
    "multibeam": ("detections", "points", "water_column", "unit"), "fls": ("image", "unit"),
}
_DOWN_LOOKING = ("sidescan", "singlebeam", "multibeam")
_DETECT_BAD_SONAR = 1
_RANGE_ULTRASOUND = 0
_CLOUD_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
_FRAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_/]*$")


@dataclass(frozen=True)
class InstrumentBagNames:
    """Names of the frames every instrument hangs from.

    Attributes
    ----------
    world : str
        The scene's world frame (z up).
    vehicle : str
        The vehicle (x forward, y port, z up): ``world -> vehicle`` per ping, the mounts below it.
    """

    world: str = "world"
    vehicle: str = "vehicle"

    def __post_init__(self) -> None:
        for key in ("world", "vehicle"):
            name = getattr(self, key)
            if not isinstance(name, str) or not _FRAME_RE.match(name):
                raise ConfigError(f"rosbag.frame_ids.{key}", "must be a ROS frame name (a letter or '_', then letters, "
                                  f"digits, '_' or '/'), got {shown(name)}")
        if self.world == self.vehicle:
            raise ConfigError("rosbag.frame_ids", f"world and vehicle need distinct names, got {self.world!r} twice")


def instrument_topics(name: str, type_name: str) -> dict[str, str]:
    """The topics an instrument's messages go to: suffix -> ``/NAME/suffix``."""
    return {key: f"/{name}/{key}" for key in _TOPICS_OF_TYPE[type_name]}


def beam_unit_vectors(tx_rad: np.ndarray, rx_rad: np.ndarray) -> np.ndarray:
    """Beam directions in a message frame from transmit and receive angles.

    Parameters
    ----------
    tx_rad, rx_rad : (n,) array_like
        Out-of-fan-plane (towards +X) and in-plane (towards +Y) angles, radians.

    Returns
    -------
    (n, 3) float64 ndarray
        ``(sin tx, cos tx sin rx, cos tx cos rx)``.
    """
    tx = np.asarray(tx_rad, np.float64)
    rx = np.asarray(rx_rad, np.float64)
    return np.stack([np.sin(tx), np.cos(tx) * np.sin(rx), np.cos(tx) * np.cos(rx)], axis=-1)


def recording_poses(film: Any) -> list[Pose]:
    """The vehicle's pose at each ping of a RECORDING's film, from the geometry it logged: the
    position ``(x_m, y_m, -depth_m)`` (depth below the surface as world z < 0) and the
    attitude ``rpy = (roll, pitch, 90 - heading)`` (REP-103, the films' conventions).

    A value a ping does not log (NaN) is the nearest earlier ping's, else the nearest later's,
    else 0 (a recording without positions stays at the origin). The sonar is taken to be at
    the vehicle's origin: give the scene's instrument an identity mount (the logged position is
    the sonar's, or the vehicle's navigation point: the file does not say which).

    Parameters
    ----------
    film : Waterfall, Envelope, Soundings or ScanImage
        Anything with ``geometry`` (:class:`~sonarsim.image.films.PingGeometry`).

    Returns
    -------
    list of Pose
        Vehicle-to-world, one per ping.
    """
    g = film.geometry

    def filled(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, np.float64).copy()
        ok = np.isfinite(a)
        if not ok.any():
            return np.zeros_like(a)
        idx = np.where(ok, np.arange(len(a)), -1)
        np.maximum.accumulate(idx, out=idx)  # the last known ping at or before each
        first = int(np.argmax(ok))
        idx[idx < 0] = first  # before the first known value: that value
        return a[idx]

    x, y, depth = filled(g.x_m), filled(g.y_m), filled(g.depth_m)
    roll, pitch, heading = filled(g.roll_deg), filled(g.pitch_deg), filled(g.heading_deg)
    yaw = _wrap_deg(90.0 - heading)
    return [Pose((float(x[k]), float(y[k]), float(-depth[k])), (float(roll[k]), float(pitch[k]), float(yaw[k])))
            for k in range(len(g))]


# The writer ---------------------------------------------------------------------------------


def instrument_typestore() -> Any:
    """The typestore of :mod:`sonarsim.io.rosbag` (Humble's messages and ProjectedSonarImage's),
    with every message the instruments' bags write added (once: adding types changes nothing
    for the FLS writer, as a bag lists only the types it uses). Raises
    :class:`~sonarsim.errors.SonarsimError` naming the ``ros`` extra without ``rosbags``."""
    store = rb._import_rosbags()[2]
    if "marine_acoustic_msgs/msg/RawSonarImage" not in store.types:
        from rosbags.typesys import get_types_from_msg

        types: dict[str, Any] = {}
        for name, text in _MSG_DEFS.items():
            types.update(get_types_from_msg(text, name))
        store.register(types)
    return store


class InstrumentMessages(rb.FrameMessages):
    """The parts of the instruments' messages, built from ``rosbags`` classes: one home for
    them whether they go into a bag (:class:`InstrumentBagWriter`) or onto live topics
    (:mod:`sonarsim.live.instruments`).

    Parameters
    ----------
    typestore : rosbags typestore, optional
        Default :func:`instrument_typestore`.
    frame_ids : BagFrameIds, optional
    """

    #: The message types the parts are built of, beyond :attr:`FrameMessages.TYPES`.
    PART_TYPES = ("sensor_msgs/msg/Range", "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/PointCloud2",
                  "std_msgs/msg/String", *_MSG_DEFS, "marine_acoustic_msgs/msg/ProjectedSonarImage")

    def __init__(self, typestore: Any = None, frame_ids: rb.BagFrameIds | None = None) -> None:
        store = typestore if typestore is not None else instrument_typestore()
        super().__init__(store, frame_ids)
        self._add_part_types(store)

    def _add_part_types(self, store: Any) -> None:
        for name in self.PART_TYPES:
            self._types[name] = store.types[name]

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        return self._header(int(stamp_ns), frame_id)

    def string(self, text: str) -> Any:
        """A ``std_msgs/String`` holding ``text``."""
        return self._types["std_msgs/msg/String"](data=str(text))

    def transform(self, stamp_ns: int, parent: str, child: str, translation: Any, quat_xyzw: Any) -> Any:
        t = self._types
        x, y, z = (float(v) for v in translation)
        qx, qy, qz, qw = (float(v) for v in quat_xyzw)
        return t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp_ns, parent), child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))

    def transforms_message(self, transforms: list) -> Any:
        """A ``tf2_msgs/TFMessage`` of ``transforms`` (:meth:`transform`'s)."""
        return self._types["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def ping_info(self, frequency_hz: float, sound_speed_m_s: float, tx_bw_rad: Any, rx_bw_rad: Any) -> Any:
        return self._types["marine_acoustic_msgs/msg/PingInfo"](
            frequency=float(frequency_hz), sound_speed=float(sound_speed_m_s),
            tx_beamwidths=np.asarray(tx_bw_rad, np.float32).reshape(-1),
            rx_beamwidths=np.asarray(rx_bw_rad, np.float32).reshape(-1))

    def image_data(self, samples: np.ndarray) -> Any:
        """``SonarImageData`` of ``(n_rows, n_beams)`` samples, row-major, little-endian."""
        a = np.ascontiguousarray(samples)
        a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
        return self._types["marine_acoustic_msgs/msg/SonarImageData"](
            is_bigendian=False, dtype=rb._SONAR_DTYPES[a.dtype.newbyteorder("=")], beam_count=int(a.shape[1]),
            data=a.reshape(-1).view(np.uint8))

    def raw_image(self, stamp_ns: int, frame_id: str, info: Any, sample_rate_hz: float, sample0: int,
                  samples: np.ndarray, tx_rad: Any, rx_rad: Any) -> Any:
        n_rows, n_beams = samples.shape
        return self._types["marine_acoustic_msgs/msg/RawSonarImage"](
            header=self.header(stamp_ns, frame_id), ping_info=info, sample_rate=float(sample_rate_hz),
            samples_per_beam=int(n_rows), sample0=int(sample0), tx_delays=np.zeros(n_beams, np.float32),
            tx_angles=np.asarray(tx_rad, np.float32).reshape(n_beams),
            rx_angles=np.asarray(rx_rad, np.float32).reshape(n_beams), image=self.image_data(samples))

    def projected_image(self, stamp_ns: int, frame_id: str, info: Any, polar: np.ndarray, range_m: Any,
                        azimuth_deg: Any) -> Any:
        vec = self._types["geometry_msgs/msg/Vector3"]
        dirs = rb.beam_directions(azimuth_deg)
        return self._types["marine_acoustic_msgs/msg/ProjectedSonarImage"](
            header=self.header(stamp_ns, frame_id), ping_info=info,
            beam_directions=[vec(x=float(x), y=float(y), z=float(z)) for x, y, z in dirs],
            ranges=np.asarray(range_m, np.float32), image=self.image_data(polar))

    def detections(self, stamp_ns: int, frame_id: str, info: Any, twtt_s: np.ndarray, intensity: np.ndarray,
                   rx_rad: np.ndarray) -> Any:
        t = self._types
        flag = t["marine_acoustic_msgs/msg/DetectionFlag"]
        bad = ~np.isfinite(twtt_s)
        n = len(twtt_s)
        return t["marine_acoustic_msgs/msg/SonarDetections"](
            header=self.header(stamp_ns, frame_id), ping_info=info,
            flags=[flag(flag=_DETECT_BAD_SONAR if b else 0) for b in bad],
            two_way_travel_times=np.asarray(twtt_s, np.float32), tx_delays=np.zeros(n, np.float32),
            intensities=np.asarray(intensity, np.float32), tx_angles=np.zeros(n, np.float32),
            rx_angles=np.asarray(rx_rad, np.float32))

    def cloud(self, stamp_ns: int, frame_id: str, points: np.ndarray, intensity: np.ndarray) -> Any:
        t = self._types
        n = len(points)
        c = np.empty(n, _CLOUD_DTYPE)
        if n:
            c["x"], c["y"], c["z"] = np.asarray(points, np.float64).T
            c["intensity"] = intensity
        field = t["sensor_msgs/msg/PointField"]
        fields = [field(name=k, offset=_CLOUD_DTYPE.fields[k][1], datatype=rb._POINTFIELD_FLOAT32, count=1)
                  for k in _CLOUD_DTYPE.names]
        return t["sensor_msgs/msg/PointCloud2"](
            header=self.header(stamp_ns, frame_id), height=1, width=n, fields=fields, is_bigendian=False,
            point_step=_CLOUD_DTYPE.itemsize, row_step=_CLOUD_DTYPE.itemsize * n, data=c.view(np.uint8),
            is_dense=bool(np.all(np.isfinite(c["intensity"]))))

    def range_msg(self, stamp_ns: int, frame_id: str, fov_rad: float, min_m: float, max_m: float,
                  range_m: float) -> Any:
        return self._types["sensor_msgs/msg/Range"](
            header=self.header(stamp_ns, frame_id), radiation_type=_RANGE_ULTRASOUND, field_of_view=float(fov_rad),
            min_range=float(min_m), max_range=float(max_m), range=float(range_m) if math.isfinite(range_m) else math.inf)


class InstrumentBagWriter(rb.BagWriter, InstrumentMessages):
    """A :class:`~sonarsim.io.rosbag.BagWriter` (atomic, either storage) that writes any
    registered message to any topic, its messages built by :class:`InstrumentMessages`;
    :func:`write_instrument_bag` drives it.

    Parameters
    ----------
    path, storage
        As :class:`~sonarsim.io.rosbag.BagWriter`.
    """

    def open(self) -> InstrumentBagWriter:
        super().open()
        try:
            self._add_part_types(instrument_typestore())
        except BaseException:
            self._discard()
            raise
        self._topic_connections: dict[str, Any] = {}
        return self

    def __enter__(self) -> InstrumentBagWriter:
        return self.open()

    def set_custom_data(self, key: str, value: str) -> None:
        """A ``custom_data`` entry of ``metadata.yaml`` (text)."""
        self._writer.set_custom_data(key, value)

    def write_message(self, topic: str, msgtype: str, msg: Any, stamp_ns: int, qos: Sequence[Any] = ()) -> None:
        """Serialize ``msg`` (CDR) and write it at bag time ``stamp_ns``; the topic's connection
        is added at its first message (with ``qos``, the offered QoS profiles)."""
        if self._writer is None:
            raise SonarsimError(f"{self.path}: the bag is not open (use 'with InstrumentBagWriter(...) as bag')")
        try:
            conn = self._topic_connections.get(topic)
            if conn is None:
                conn = self._writer.add_connection(topic, msgtype, typestore=self._typestore,
                                                   offered_qos_profiles=list(qos))
                self._topic_connections[topic] = conn
            self._writer.write(conn, int(stamp_ns), self._typestore.serialize_cdr(msg, msgtype))
        except OSError as exc:
            raise SonarsimError(f"{self.path}: cannot write the bag: {exc.strerror or exc}") from None
        self.frames_written += 1


# Films -> messages --------------------------------------------------------------------------


def _static_qos() -> list:
    """The QoS tf2's static broadcaster offers: reliable, transient-local, keep last 1."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    never = QosTime(sec=0x7FFFFFFF, nsec=0xFFFFFFFF)
    return [Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
                durability=QosDurability.TRANSIENT_LOCAL, deadline=never, lifespan=never,
                liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=never,
                avoid_ros_namespace_conventions=False)]


def _specs(scene: Any) -> dict[str, Any]:
    from ..config.instruments import FlsSpec

    scene = getattr(scene, "scene", scene)  # a Simulator or its Scene
    specs = scene.instruments or (FlsSpec(name="sonar", sonar=scene.sonar),)
    return {s.name: s for s in specs}


def _film_type(film: Any) -> str:
    from ..image.films import Envelope, Soundings, Waterfall
    from ..instruments.scanning import ScanImage

    for cls, name in ((Waterfall, "sidescan"), (ScanImage, "scanning"), (Envelope, "singlebeam"),
                      (Soundings, "multibeam")):
        if isinstance(film, cls):
            return name
    if isinstance(film, Sequence) and all(hasattr(f, "polar") and hasattr(f, "azimuth_deg") for f in film):
        return "fls"
    return type(film).__name__


def _n_pings(film: Any, kind: str) -> int:
    if kind == "fls":
        return len(film)
    if kind == "scanning":
        return film.n_steps
    return film.n_pings


def _film_times(film: Any, kind: str, spec: Any) -> np.ndarray | None:
    if kind == "fls":
        return None
    return np.asarray(film.geometry.time_s, np.float64)


def _window(range_min_m: float, range_max_m: float, n_samples: int, key: str) -> tuple[float, int]:
    """``(dr, sample0)`` of a film's range window."""
    dr = (float(range_max_m) - float(range_min_m)) / int(n_samples)
    if not (math.isfinite(dr) and dr > 0 and range_min_m >= 0):
        raise ConfigError(key, f"needs a range window 0 <= range_min_m < range_max_m, got "
                          f"[{range_min_m!r}, {range_max_m!r}]")
    return dr, int(math.floor(float(range_min_m) / dr + 0.5))  # nearest, halves up


def _sound_speed(film: Any, spec: Any, k: int) -> float:
    c = float(film.geometry.sound_speed_m_s[k]) if hasattr(film, "geometry") else math.nan
    if not (math.isfinite(c) and c > 0):
        c = float(getattr(spec, "sound_speed_m_s", 0.0) or 1500.0)
    return c


def _frequency_hz(spec: Any) -> float:
    khz = getattr(spec, "frequency_khz", None)
    if not khz:
        try:
            khz = spec.channels()[0].sonar.frequency_khz
        except Exception:  # noqa: BLE001 - unknown is written as 0
            khz = None
    return 1000.0 * float(khz) if khz else 0.0


def _wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles to (-180, 180] degrees."""
    return 180.0 - np.mod(180.0 - np.asarray(a, np.float64), 360.0)


class _Instrument:
    """One instrument's film and what its messages need (frames, topics, widths)."""

    def __init__(self, name: str, spec: Any, film: Any, kind: str, poses: list, stamps: list[int],
                 vehicle_frame: str) -> None:
        self.name, self.spec, self.film, self.kind = name, spec, film, kind
        self.vehicle_frame = vehicle_frame
        self.poses, self.stamps = poses, stamps
        self.frame = name
        self.image_frame = f"{name}_image"
        self.beam_frame = f"{name}_beam"
        self.topics = instrument_topics(name, kind)
        self.frequency_hz = _frequency_hz(spec)

    def describe(self) -> dict:
        """What ``custom_data`` records of this instrument (the exact windows among it)."""
        out: dict[str, Any] = {"type": self.kind, "frame": self.frame, "image_frame": self.image_frame,
                               "topics": self.topics, "pings": len(self.stamps), "unit": self.unit}
        f = self.film
        if self.kind in ("sidescan", "scanning", "singlebeam"):
            n = f.n_samples if self.kind != "singlebeam" else f.samples.shape[1]
            out.update(range_min_m=float(f.range_min_m), range_max_m=float(f.range_max_m), n_samples=int(n))
        if self.kind == "singlebeam":
            out["beam_frame"] = self.beam_frame
        return out

    def static_transforms(self, bag: InstrumentMessages, stamp_ns: int, vehicle: str) -> list:
        m = self.spec.mount
        image_q = DOWN_TO_IMAGE_QUAT_XYZW if self.kind in _DOWN_LOOKING else rb.SONAR_TO_IMAGE_QUAT_XYZW
        out = [bag.transform(stamp_ns, vehicle, self.frame, m.position_m, m.quat_xyzw),
               bag.transform(stamp_ns, self.frame, self.image_frame, (0.0, 0.0, 0.0), image_q)]
        if self.kind == "singlebeam":
            out.append(bag.transform(stamp_ns, self.frame, self.beam_frame, (0.0, 0.0, 0.0), _BEAM_QUAT_XYZW))
        return out

    @property
    def unit(self) -> str:
        """The film's unit (:mod:`sonarsim.image.units`): its ``unit_name``, an FLS's images' unit."""
        f = self.film
        if self.kind == "fls":
            return f[0].unit.name if len(f) else "backscatter"
        return f.unit_name

    def messages(self, bag: InstrumentMessages, k: int) -> list[tuple[str, str, Any]]:
        """Ping ``k``'s ``(topic, msgtype, message)``; the first ping's with the film's unit."""
        out = self.ping_messages(bag, k)
        if k == 0:
            out.append(self.unit_message(bag))
        return out

    def ping_messages(self, bag: InstrumentMessages, k: int) -> list[tuple[str, str, Any]]:
        """Ping ``k``'s ``(topic, msgtype, message)``, at its stamp ``stamps[k]``."""
        return getattr(self, f"_{self.kind}")(bag, k, self.stamps[k])

    def unit_message(self, bag: InstrumentMessages) -> tuple[str, str, Any]:
        """``(topic, msgtype, message)`` of the film's unit."""
        return (self.topics["unit"], INSTRUMENT_MSGTYPES["unit"], bag.string(self.unit))

    def _raw(self, bag, key: str, stamp: int, k: int, window: tuple, n_samples: int, samples: np.ndarray,
             tx_deg: Any, rx_deg: Any, tx_bw_deg: Any, rx_bw_deg: Any) -> tuple:
        c = _sound_speed(self.film, self.spec, k)
        dr, sample0 = _window(*window, n_samples, f"{self.name}.range window")
        info = bag.ping_info(self.frequency_hz, c, np.radians(tx_bw_deg), np.radians(rx_bw_deg))
        msg = bag.raw_image(stamp, self.image_frame, info, c / (2.0 * dr), sample0, samples,
                            np.radians(tx_deg), np.radians(rx_deg))
        return (self.topics[key], INSTRUMENT_MSGTYPES[key], msg)

    def _sidescan(self, bag, k: int, stamp: int) -> list:
        f, s = self.film, self.spec
        a = 90.0 - float(s.depression_deg)
        samples = np.asarray(f.samples[k], np.float32).T  # (n_samples, 2): port beam 0, starboard 1
        return [self._raw(bag, "raw", stamp, k, (f.range_min_m, f.range_max_m), f.n_samples, samples,
                          [0.0, 0.0], [-a, a], [s.horizontal_beam_width_deg] * 2, [s.vertical_beam_width_deg] * 2)]

    def _scanning(self, bag, k: int, stamp: int) -> list:
        f, s = self.film, self.spec
        samples = np.asarray(f.samples[:, k], np.float32)[:, None]
        rx = -_wrap_deg(f.angle_deg[k])
        rx = 180.0 if rx == -180.0 else rx  # keep the interval (-180, 180]
        return [self._raw(bag, "raw", stamp, k, (f.range_min_m, f.range_max_m), f.n_samples, samples,
                          [-float(s.tilt_deg)], [rx], [s.vertical_beam_width_deg], [s.horizontal_beam_width_deg])]

    def _singlebeam(self, bag, k: int, stamp: int) -> list:
        f, s = self.film, self.spec
        n = f.samples.shape[1]
        samples = np.asarray(f.samples[k], np.float32)[:, None]
        w = float(s.beam_width_deg)
        raw = self._raw(bag, "raw", stamp, k, (f.range_min_m, f.range_max_m), n, samples, [0.0], [0.0], [w], [w])
        rng = bag.range_msg(stamp, self.beam_frame, math.radians(w), f.range_min_m, f.range_max_m,
                            float(f.bottom_range_m[k]))
        return [raw, (self.topics["range"], INSTRUMENT_MSGTYPES["range"], rng)]

    def _multibeam(self, bag, k: int, stamp: int) -> list:
        f, s = self.film, self.spec
        c = _sound_speed(f, s, k)
        angle = np.asarray(f.angle_deg[k], np.float64)
        tx_bw, rx_bw = self._multibeam_widths(f.n_beams)
        info = bag.ping_info(self.frequency_hz, c, np.radians(tx_bw), np.radians(rx_bw))
        twtt = np.asarray(f.two_way_time_s[k], np.float64)
        out = [(self.topics["detections"], INSTRUMENT_MSGTYPES["detections"],
                bag.detections(stamp, self.image_frame, info, twtt, f.intensity[k], -np.radians(angle)))]
        # The soundings in the vehicle frame: straight rays in the head (mount) frame, moved by the mount.
        r = twtt * c / 2.0
        a = np.radians(angle)
        head = np.stack([np.zeros_like(r), r * np.sin(a), -r * np.cos(a)], axis=-1)
        ok = np.isfinite(r)
        m = s.mount
        pts = head[ok] @ m.rotation.T + m.translation
        out.append((self.topics["points"], INSTRUMENT_MSGTYPES["points"],
                    bag.cloud(stamp, self.vehicle_frame, pts, np.asarray(f.intensity[k], np.float32)[ok])))
        if f.water_column is not None:
            wc = np.asarray(f.water_column[k], np.float32)  # (n_samples, n_beams)
            g = f.geometry
            lo, hi = float(g.range_min_m[k]), float(g.range_max_m[k])
            if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
                raise ConfigError(f"{self.name}.geometry.range_min_m",
                                  f"ping {k}: a water column needs its range window, got [{lo}, {hi}]")
            from ..image.films import range_axis

            out.append((self.topics["water_column"], INSTRUMENT_MSGTYPES["water_column"],
                        bag.projected_image(stamp, self.image_frame, info, wc, range_axis(lo, hi, wc.shape[0]),
                                            angle)))
        return out

    def _multibeam_widths(self, n_beams: int) -> tuple[Any, Any]:
        """Per-beam transmit (along-track) and receive widths, degrees, from the spec's fan if it
        has one beam per sounding; empty (unknown) otherwise."""
        try:
            sonar = self.spec.channels()[0].sonar
            if sonar.n_beams == n_beams:
                return np.full(n_beams, sonar.elevation_fov_deg), sonar.effective_beam_width_deg()
        except Exception:  # noqa: BLE001 - a spec without a fan: widths unknown
            pass
        return np.zeros(0), np.zeros(0)

    def _fls(self, bag, k: int, stamp: int) -> list:
        image = self.film[k]
        frame = rb.frame_from_image(image, stamp, fan=False)  # validated; its conventions
        info = bag.ping_info(frame.frequency_hz, frame.sound_speed_m_s, np.radians(frame.tx_beamwidth_deg),
                             np.radians(frame.rx_beamwidth_deg))
        return [(self.topics["image"], INSTRUMENT_MSGTYPES["image"],
                 bag.projected_image(stamp, self.image_frame, info, frame.polar, frame.range_m, frame.azimuth_deg))]


def write_instrument_bag(
    path: str | os.PathLike,
    films: Mapping[str, Any],
    scene: Any,
    *,
    poses: Mapping[str, Sequence[Pose]] | None = None,
    times_s: Mapping[str, Any] | None = None,
    start_ns: int = rb.DEFAULT_START_NS,
    storage: str = "mcap",
    names: InstrumentBagNames | None = None,
) -> Path:
    """Write the films of a scene's instruments to a ROS 2 bag (see the module's notes).

    Parameters
    ----------
    path : str or os.PathLike
        The bag folder to create (it must not exist; its parent must).
    films : mapping of str to film
        Instrument name -> its film: a :class:`~sonarsim.image.films.Waterfall` (side-scan),
        :class:`~sonarsim.instruments.scanning.ScanImage`, :class:`~sonarsim.image.films.Envelope`
        (single-beam), :class:`~sonarsim.image.films.Soundings` (multibeam), or a list of
        :class:`~sonarsim.image.result.SonarImage` (FLS), as ``render_pings`` returns them.
    scene : Scene or Simulator
        Where the instruments' specs (mounts, beam widths, depression, tilt) come from.
    poses : mapping of str to sequence of Pose, optional
        Per instrument the vehicle's pose (vehicle-to-world) at each ping: what the film was
        rendered at (with a trajectory, give them: ``vehicle_poses(sim, spec, trajectory=...)``).
        Default: the scene's vehicle at each ping's time (standing, or running ahead at
        ``vehicle.speed_m_s``), which is what ``render_pings`` without a trajectory used.
    times_s : mapping of str to (n,) array, optional
        Ping times, seconds, replacing a film's ``geometry.time_s``; an FLS film carries none,
        and defaults to the instrument's ping period times the ping index.
    start_ns : int
        Stamp of the earliest ping, nanoseconds since 1970 (> 0,
        :func:`~sonarsim.io.rosbag.parse_start_time`).
    storage : {"mcap", "sqlite3"}
    names : InstrumentBagNames, optional
        The world and vehicle frame names.

    Returns
    -------
    pathlib.Path
        The bag folder.

    Raises
    ------
    ConfigError
        An instrument the scene lacks, a film of the wrong type for its instrument, poses or
        times not one per ping, two instruments putting the vehicle at two poses at one time, a
        name that is no ROS frame name, a stamp past 2038.

    Examples
    --------
    A recording (its logged geometry as the vehicle's poses, its own times as the stamps):

    >>> w = read_waterfall("survey.xtf")                                   # doctest: +SKIP
    >>> scene = sonarsim.load_scene({"instruments": [{"type": "sidescan", "name": "sss",
    ...     "preset": "seascan_hds_600"}]})                                # doctest: +SKIP
    >>> write_instrument_bag("survey_bag", {"sss": w}, scene, poses={"sss": recording_poses(w)},
    ...     start_ns=parse_start_time(float(w.geometry.time_s[0])))        # doctest: +SKIP
    """
    from ..instruments import vehicle_poses

    names = names if names is not None else InstrumentBagNames()
    specs = _specs(scene)
    sim_like = type("_SceneOnly", (), {"scene": getattr(scene, "scene", scene)})()
    if not isinstance(films, Mapping) or not films:
        raise ConfigError("films", f"must map instrument names to films, got {shown(films)}")
    instruments: list[_Instrument] = []
    pending: list[tuple[str, Any, Any, str, np.ndarray]] = []
    for name, film in films.items():
        if name not in specs:
            raise ConfigError(f"films.{name}", f"no such instrument in the scene; it has: {', '.join(specs)}")
        if not _FRAME_RE.match(name) or name in (names.world, names.vehicle):
            raise ConfigError(f"films.{name}", "an instrument's name names its frames and topics: it must be a ROS "
                              "name (a letter or '_', then letters, digits, '_') other than the world's and vehicle's")
        spec = specs[name]
        kind = _film_type(film)
        if kind != spec.type_name:
            raise ConfigError(f"films.{name}", f"the instrument is a {spec.type_name}; its film cannot be a "
                              f"{type(film).__name__} (a {kind}'s)")
        n = _n_pings(film, kind)
        t = _film_times(film, kind, spec)
        if times_s is not None and name in times_s:
            t = np.asarray(times_s[name], np.float64)
        if t is None:
            t = spec.ping_period_s() * np.arange(n)
        if t.shape != (n,) or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
            raise ConfigError(f"times_s.{name}", f"must be {n} finite ascending times (one per ping), got shape {t.shape}")
        pending.append((name, spec, film, kind, t))
    t0 = min(float(p[4][0]) for p in pending if len(p[4]))
    base = rb._seconds_ns(repr(t0))
    for name, spec, film, kind, t in pending:
        if poses is not None and name in poses:
            vp = list(poses[name])
        else:
            vp, _ = vehicle_poses(sim_like, spec, times_s=t - t0 if len(t) else t)
        if len(vp) != len(t) or not all(isinstance(p, Pose) for p in vp):
            raise ConfigError(f"poses.{name}", f"must be {len(t)} Poses (one per ping), got {len(vp)}")
        stamps = [int(start_ns) + rb._seconds_ns(repr(float(x))) - base for x in t]
        if stamps and (stamps[0] <= 0 or stamps[-1] >= rb._MAX_STAMP_NS):
            raise ConfigError("start_time", "the pings' stamps must lie in (1970, 2038-01-19T03:14:08Z); "
                              f"the last would be {rb.format_stamp(max(stamps[-1], 0))}")
        instruments.append(_Instrument(name, spec, film, kind, vp, stamps, names.vehicle))

    # Every ping of every instrument, in time order (ties: the films' order, then ping order).
    order = sorted((inst.stamps[k], i, k) for i, inst in enumerate(instruments) for k in range(len(inst.stamps)))
    # One vehicle: instruments pinging at one stamp must put it at one pose (/tf holds one).
    at: dict[int, tuple[int, int]] = {}
    for stamp, i, k in order:
        if stamp in at:
            j, q = at[stamp]
            if not np.allclose(instruments[i].poses[k].matrix(), instruments[j].poses[q].matrix(), atol=1e-9):
                raise ConfigError(f"poses.{instruments[i].name}",
                                  f"ping {k} is at the time of {instruments[j].name}'s ping {q} "
                                  f"({rb.format_stamp(stamp)}) but puts the vehicle elsewhere")
        else:
            at[stamp] = (i, k)
    with InstrumentBagWriter(path, storage=storage) as bag:
        bag.set_custom_data("sonarsim.instruments", json.dumps(
            {inst.name: inst.describe() for inst in instruments}, sort_keys=True))
        first = order[0][0] if order else int(start_ns)
        static = [tf for inst in instruments for tf in inst.static_transforms(bag, first, names.vehicle)]
        bag.write_message("/tf_static", "tf2_msgs/msg/TFMessage", bag.transforms_message(static), first, qos=_static_qos())
        last_tf = None
        for stamp, i, k in order:
            inst = instruments[i]
            if stamp != last_tf:  # one world -> vehicle per stamp (instruments pinging together share it)
                v = inst.poses[k]
                bag.write_message("/tf", "tf2_msgs/msg/TFMessage", bag.transforms_message(
                    [bag.transform(stamp, names.world, names.vehicle, v.position_m, v.quat_xyzw)]), stamp)
                last_tf = stamp
            for topic, msgtype, msg in inst.messages(bag, k):
                bag.write_message(topic, msgtype, msg, stamp)
    return Path(path)
