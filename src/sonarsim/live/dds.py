"""ROS 2's wire format without ROS: topics and message types on DDS (``DESIGN.md`` section 14).

A ROS 2 topic ``/sonar/image`` is the DDS topic ``rt/sonar/image`` (:func:`dds_topic`); a
message type ``marine_acoustic_msgs/msg/ProjectedSonarImage`` is the DDS type
``marine_acoustic_msgs::msg::dds_::ProjectedSonarImage_`` (:func:`dds_typename`), a final struct
whose payload is the message's CDR (XCDR1, little-endian), the bytes a rosbag2 file stores.

The DDS types are not written by hand: :func:`dds_type` builds each from the same message
definitions the bags are written with (``rosbags``' typestore, with the marine acoustics
messages sonarsim registers: :func:`sonarsim.io.rosbag_instruments.instrument_typestore`), as a
Cyclone DDS ``IdlStruct``, so that one definition serves bags and live topics alike;
:func:`to_sample` turns a ``rosbags`` message into its sample. The tests hold the two
serialisations equal byte for byte for every message sonarsim writes.

QoS as ROS 2 sets it: :data:`SENSOR_DATA_QOS` for sensor topics (best effort, keep last 5,
volatile: a slow subscriber loses samples, the publisher never waits) and
:data:`TF_STATIC_QOS` for ``/tf_static`` (reliable, transient local, keep last 1: a late
subscriber still receives the static transforms). :func:`domain_id` reads ``ROS_DOMAIN_ID``.

Needs the ``live`` extra (``cyclonedds`` and ``rosbags``); without it the first call raises
:class:`~sonarsim.errors.SonarsimError` naming the extra.
"""

from __future__ import annotations

import functools
import os
import re
from typing import Any

import numpy as np

from ..core.extras import install_hint
from ..errors import ConfigError, SonarsimError

__all__ = ["QOS_KINDS", "ROS_DOMAIN_ID_RANGE", "RawSample", "dds_topic", "dds_type", "dds_typename", "domain_id", "qos",
           "padded", "raw_type", "serialized_sample", "to_sample", "unpadded"]

#: The domain ids ROS 2 allows (``ROS_DOMAIN_ID``; 0 by default).
ROS_DOMAIN_ID_RANGE = (0, 232)

_ROS_TYPE_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*$")
_ROS_TOPIC_RE = re.compile(r"^/?[A-Za-z_~][A-Za-z0-9_/]*$")
# rosbags' names of the ROS 2 primitive types -> Cyclone DDS's (a ROS 2 char and byte are octets).
_PRIMITIVES = ("bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
               "float32", "float64", "octet")
# rosbags' node kinds (rosbags.interfaces.Nodetype): a primitive, a named message, an array, a sequence.
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4
# numpy dtypes of the primitive kinds' sequences, for the conversion to Python values.
_BYTES = ("byte", "char", "uint8", "octet")


def _cyclonedds() -> Any:
    try:
        import cyclonedds.idl as idl
        import cyclonedds.idl.annotations as annotate
        import cyclonedds.idl.types as types
    except ImportError as exc:
        raise SonarsimError(f"live ROS 2 topics need Cyclone DDS ({exc}); {install_hint('live')}") from None
    return idl, annotate, types


def dds_topic(ros_topic: str) -> str:
    """The DDS topic of a ROS 2 topic: ``/sonar/image`` -> ``rt/sonar/image``.

    Raises
    ------
    ConfigError
        Not a ROS 2 topic name (letters, digits, ``_`` and ``/``, not ending in ``/``).
    """
    if not isinstance(ros_topic, str) or not _ROS_TOPIC_RE.match(ros_topic) or ros_topic.endswith("/") \
            or "//" in ros_topic:
        raise ConfigError("topic", f"must be a ROS 2 topic name such as /sonar/image, got {ros_topic!r}")
    return "rt/" + ros_topic.lstrip("/")


def dds_typename(ros_type: str) -> str:
    """The DDS type of a ROS 2 message type: ``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_``."""
    if not isinstance(ros_type, str) or not _ROS_TYPE_RE.match(ros_type):
        raise ConfigError("type", f"must be a ROS 2 message type such as sensor_msgs/msg/Image, got {ros_type!r}")
    package, _, name = ros_type.split("/")
    return f"{package}::msg::dds_::{name}_"


@functools.lru_cache(maxsize=1)
def _typestore() -> Any:
    from ..io.rosbag_instruments import instrument_typestore

    return instrument_typestore()


def _field_type(node: tuple, where: str) -> Any:
    _, _, types = _cyclonedds()
    kind, arg = node
    kind = int(kind)
    if kind == _BASE:
        name, bound = arg
        if name == "string":
            return types.bounded_str[bound] if bound else str
        if name not in _PRIMITIVES:
            raise SonarsimError(f"{where}: the ROS 2 type {name!r} has no DDS mapping here")
        return bool if name == "bool" else getattr(types, "uint8" if name in _BYTES else name)
    if kind == _NAME:
        return dds_type(arg)
    if kind == _ARRAY:
        sub, n = arg
        return types.array[_field_type(sub, where), n]
    if kind == _SEQUENCE:
        sub, n = arg
        return types.sequence[_field_type(sub, where), n] if n else types.sequence[_field_type(sub, where)]
    raise SonarsimError(f"{where}: unknown field kind {kind}")


@functools.lru_cache(maxsize=None)
def dds_type(ros_type: str) -> type:
    """The Cyclone DDS ``IdlStruct`` of a ROS 2 message type, from its ``rosbags`` definition.

    Parameters
    ----------
    ros_type : str
        ``pkg/msg/Name``, a type of :func:`~sonarsim.io.rosbag_instruments.instrument_typestore`
        (Humble's standard messages and the marine acoustics messages sonarsim writes).

    Returns
    -------
    type
        A final struct named :func:`dds_typename` whose fields are the message's, in order.
    """
    idl, annotate, _ = _cyclonedds()
    typename = dds_typename(ros_type)
    store = _typestore()
    if ros_type not in store.fielddefs:
        raise ConfigError("type", f"{ros_type} is not a message sonarsim knows")
    _, fields = store.fielddefs[ros_type]
    cls = idl.make_idl_struct(ros_type.rsplit("/", 1)[1] + "_", typename,
                              {name: _field_type(node, f"{ros_type}.{name}") for name, node in fields})
    return annotate.final(cls)


def _value(value: Any, node: tuple) -> Any:
    kind, arg = node
    kind = int(kind)
    if kind == _NAME:
        return to_sample(value, arg)
    if kind in (_ARRAY, _SEQUENCE):
        (sub_kind, sub_arg), _ = arg
        if int(sub_kind) == _NAME:
            return [to_sample(v, sub_arg) for v in value]
        if int(sub_kind) == _BASE and sub_arg[0] in _BYTES:
            # octets travel as one bytes object (Cyclone DDS copies it whole)
            return np.ascontiguousarray(value, dtype=np.uint8).tobytes()
        if isinstance(value, np.ndarray):
            return value.tolist()
        return list(value)
    if isinstance(value, np.generic):
        return value.item()
    return value


def to_sample(msg: Any, ros_type: str) -> Any:
    """A ``rosbags`` message of ``ros_type`` as its DDS sample (:func:`dds_type`); the sample's
    CDR is the message's, byte for byte."""
    _, fields = _typestore().fielddefs[ros_type]
    return dds_type(ros_type)(**{name: _value(getattr(msg, name), node) for name, node in fields})


@functools.lru_cache(maxsize=None)
def _serialized_type(ros_type: str) -> type:
    cls = dds_type(ros_type)

    def serialize(self: Any, buffer: Any = None, endianness: Any = None, use_version_2: Any = None) -> bytes:
        return self._cdr

    return type(cls.__name__, (cls,), {"serialize": serialize, "__module__": __name__})


def serialized_sample(ros_type: str, cdr: bytes) -> Any:
    """A sample of ``ros_type``'s DDS type that writes ``cdr`` as its payload: a message already
    serialised (``rosbags``' ``serialize_cdr``, the encapsulation header first), so that large
    arrays are not converted to Python values and serialised again (rosbags' serialiser copies a
    4.7 MB fan in 5 ms, Cyclone DDS's Python one takes 190 ms). Only a :class:`~cyclonedds.pub.DataWriter`
    of that type may write it; its fields are not set."""
    cls = _serialized_type(ros_type)
    sample = cls.__new__(cls)
    sample._cdr = padded(bytes(cdr))
    return sample


def padded(cdr: bytes) -> bytes:
    """A CDR payload padded to a multiple of 4 bytes, as DDS sends it, with the number of
    padding bytes in the low two bits of the encapsulation options (DDS-XTypes 1.3, 7.6.3.1.2),
    so that a reader can drop them again (:func:`unpadded`)."""
    pad = -len(cdr) % 4
    if not pad or len(cdr) < 4:
        return cdr
    return cdr[:3] + bytes([(cdr[3] & ~3) | pad]) + cdr[4:] + b"\0" * pad


def unpadded(cdr: bytes) -> bytes:
    """A payload as received, less the padding its encapsulation options count: the bytes a
    ``rosbags`` serialiser gives for the message."""
    if len(cdr) < 4 or not cdr[3] & 3:
        return cdr
    pad = cdr[3] & 3
    return cdr[:3] + bytes([cdr[3] & ~3]) + cdr[4:-pad]


class RawSample:
    """A sample as it came off the wire: :attr:`cdr` is its serialised payload, the
    encapsulation header first, less the padding DDS added (the bytes a ROS 2 bag stores),
    :attr:`sample_info` what DDS said of it."""

    __slots__ = ("cdr", "sample_info")

    def __init__(self, cdr: bytes) -> None:
        self.cdr = cdr
        self.sample_info: Any = None


@functools.lru_cache(maxsize=None)
def raw_type(ros_type: str) -> type:
    """``ros_type``'s DDS type (the same name and fields as :func:`dds_type`, so that it
    matches any writer of it) whose reader hands back :class:`RawSample` objects instead of
    decoding: a recorder keeps the CDR as it came (as ``ros2 bag record`` does), without
    Python decoding large arrays and serialising them again."""
    idl, annotate, _ = _cyclonedds()
    store = _typestore()
    if ros_type not in store.fielddefs:
        raise ConfigError("type", f"{ros_type} is not a message sonarsim knows")
    _, fields = store.fielddefs[ros_type]
    cls = idl.make_idl_struct(ros_type.rsplit("/", 1)[1] + "_", dds_typename(ros_type),
                              {name: _field_type(node, f"{ros_type}.{name}") for name, node in fields})

    def deserialize(_cls: Any, data: bytes, has_header: bool = True, use_version_2: Any = None) -> RawSample:
        return RawSample(unpadded(bytes(data)))

    cls.deserialize = classmethod(deserialize)
    return annotate.final(cls)


def domain_id(environ: dict | None = None) -> int:
    """``ROS_DOMAIN_ID`` (default 0), within :data:`ROS_DOMAIN_ID_RANGE`.

    Raises
    ------
    ConfigError
        Not a whole number in range (naming ``ROS_DOMAIN_ID``).
    """
    env = os.environ if environ is None else environ
    text = env.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    lo, hi = ROS_DOMAIN_ID_RANGE
    if not text.isdigit() or not lo <= int(text) <= hi:
        raise ConfigError("ROS_DOMAIN_ID", f"must be a whole number from {lo} to {hi}, got {text!r}")
    return int(text)


def qos(kind: str) -> Any:
    """The QoS ROS 2 gives a kind of topic: ``"sensor"`` (best effort, keep last 5, volatile:
    ``rmw_qos_profile_sensor_data``), ``"tf"`` (reliable, keep last 100, volatile: tf2's
    broadcaster), ``"tf_static"`` or ``"latched"`` (reliable, transient local, keep last 1)."""
    try:
        from cyclonedds.qos import Policy, Qos
    except ImportError as exc:
        raise SonarsimError(f"live ROS 2 topics need Cyclone DDS ({exc}); {install_hint('live')}") from None
    if kind == "sensor":
        return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5), Policy.Durability.Volatile)
    if kind == "tf":
        return Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(100), Policy.Durability.Volatile)
    if kind in ("tf_static", "latched"):
        return Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(1), Policy.Durability.TransientLocal)
    raise ConfigError("qos", f"must be one of {', '.join(QOS_KINDS)}, got {kind!r}")


#: What :func:`qos` offers (``latched``: as ``tf_static``, for a topic a late subscriber must
#: still receive, such as an image's unit).
QOS_KINDS = ("sensor", "tf", "tf_static", "latched")
