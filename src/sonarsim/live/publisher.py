"""DDS writers of ROS 2 topics on one domain: what ``sonarsim live`` publishes through.

:class:`Publisher` holds one DDS participant on ``ROS_DOMAIN_ID``'s domain
(:func:`~sonarsim.live.dds.domain_id`) and a writer per topic, made at the topic's first
message with the QoS ROS 2 gives its kind (:func:`~sonarsim.live.dds.qos`). Sensor topics are
best effort: a slow or absent subscriber never makes :meth:`Publisher.publish` wait.
"""

from __future__ import annotations

from typing import Any

from ..errors import ConfigError, SonarsimError
from . import dds

__all__ = ["Publisher"]


class Publisher:
    """ROS 2 topics published over DDS (a context manager: :meth:`close` on leaving).

    Parameters
    ----------
    domain : int, optional
        The DDS domain; default ``ROS_DOMAIN_ID`` (0 where unset).
    """

    def __init__(self, domain: int | None = None) -> None:
        try:
            from cyclonedds.domain import DomainParticipant
        except ImportError as exc:
            from ..core.extras import install_hint

            raise SonarsimError(f"live ROS 2 topics need Cyclone DDS ({exc}); {install_hint('live')}") from None
        self.domain = dds.domain_id() if domain is None else int(domain)
        lo, hi = dds.ROS_DOMAIN_ID_RANGE
        if not lo <= self.domain <= hi:
            raise ConfigError("ROS_DOMAIN_ID", f"must be from {lo} to {hi}, got {self.domain}")
        self._participant: Any = DomainParticipant(self.domain)
        self._writers: dict[str, tuple[Any, str]] = {}
        self.published: dict[str, int] = {}

    @property
    def participant(self) -> Any:
        """The DDS participant (readers of the same domain are made on it: :mod:`sonarsim.live.poses`)."""
        if self._participant is None:
            raise SonarsimError("the publisher is closed")
        return self._participant

    def writer(self, topic: str, ros_type: str, kind: str = "sensor") -> Any:
        """The writer of ``topic`` (a ROS 2 name), made at first use with ``kind``'s QoS;
        a topic keeps the type it was first given."""
        if topic in self._writers:
            writer, known = self._writers[topic]
            if known != ros_type:
                raise ConfigError("topic", f"{topic} carries {known}, not {ros_type}")
            return writer
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        if self._participant is None:
            raise SonarsimError("the publisher is closed")
        q = dds.qos(kind)
        t = Topic(self._participant, dds.dds_topic(topic), dds.dds_type(ros_type), qos=q)
        writer = DataWriter(self._participant, t, qos=q)
        self._writers[topic] = (writer, ros_type)
        self.published[topic] = 0
        return writer

    def publish(self, topic: str, ros_type: str, msg: Any, kind: str = "sensor") -> None:
        """Write a ``rosbags`` message of ``ros_type`` on ``topic``: its CDR as ``rosbags``
        serialises it for a bag (:func:`~sonarsim.live.dds.serialized_sample`; the same bytes
        :func:`~sonarsim.live.dds.to_sample` gives, tested)."""
        writer = self.writer(topic, ros_type, kind)
        cdr = dds._typestore().serialize_cdr(msg, ros_type)
        writer.write(dds.serialized_sample(ros_type, cdr))
        self.published[topic] += 1

    def subscribers(self, topic: str) -> int:
        """How many readers on the domain match ``topic``'s writer now (0 before its first message)."""
        if topic not in self._writers:
            return 0
        return int(self._writers[topic][0].get_publication_matched_status().current_count)

    def close(self) -> None:
        """Delete the participant and its writers (subscribers see them go)."""
        participant, self._participant = self._participant, None
        self._writers.clear()
        if participant is not None:
            del participant  # Cyclone DDS deletes an entity when its last reference goes

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
