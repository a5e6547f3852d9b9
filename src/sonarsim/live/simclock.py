"""Simulated time: ``/clock`` (``rosgraph_msgs/Clock``), as ROS 2 nodes with ``use_sim_time`` follow it.

A simulator that runs faster or slower than the wall clock, or pauses, publishes its time on
``/clock``; ``sonarsim live --use-sim-time`` paces and stamps its frames by it: frame ``k`` is
published when the simulated time reaches ``k / rate`` after the first ``/clock`` received, and
stamped with that time (so a pose topic from the same simulator, stamped in its time, is read
at the right instant). :class:`SimClock` gives :func:`sonarsim.live.stream.stream` its ``clock``
and ``sleep``: ``sleep`` waits, polling every millisecond, until the simulated time has moved on
by the amount asked (no busy loop; a paused simulator holds the frames).
"""

from __future__ import annotations

import time
from typing import Any

from ..errors import SonarsimError
from . import dds

__all__ = ["SimClock", "POLL_S"]

#: How often :meth:`SimClock.sleep` looks at ``/clock`` while it waits, seconds.
POLL_S = 0.001


class SimClock:
    """The latest time received on a ``/clock`` topic.

    Parameters
    ----------
    participant : cyclonedds DomainParticipant
    topic : str
        Default ``/clock``.
    """

    def __init__(self, participant: Any, topic: str = "/clock") -> None:
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        # best effort matches a reliable /clock writer too; only the newest time matters
        q = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1), Policy.Durability.Volatile)
        self.topic = topic
        self._reader = DataReader(participant, Topic(participant, dds.dds_topic(topic),
                                                     dds.dds_type("rosgraph_msgs/msg/Clock"), qos=q), qos=q)
        self._now_ns: int | None = None

    def now_ns(self) -> int | None:
        """The newest simulated time received, ns (``None`` before the first)."""
        for s in self._reader.take(N=64):
            if hasattr(s, "clock"):
                t = int(s.clock.sec) * 1_000_000_000 + int(s.clock.nanosec)
                if self._now_ns is None or t > self._now_ns:
                    self._now_ns = t  # (a time that goes back is ignored: a clock only moves on)
        return self._now_ns

    def wait_first(self, timeout_s: float = 30.0, sleep: Any = time.sleep) -> int:
        """Block until a first time arrives (ns); raises :class:`SonarsimError` after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while True:
            t = self.now_ns()
            if t is not None:
                return t
            if time.monotonic() > end:
                raise SonarsimError(f"--use-sim-time: nothing arrived on {self.topic} in {timeout_s:g} s "
                                    "(is the simulator running, on this ROS_DOMAIN_ID?)")
            sleep(0.01)

    def seconds(self) -> float:
        """The simulated time, seconds (for :func:`~sonarsim.live.stream.stream`'s ``clock``)."""
        t = self.now_ns()
        if t is None:
            raise SonarsimError(f"--use-sim-time: no time received on {self.topic} yet")
        return t / 1e9

    def sleep(self, seconds: float) -> None:
        """Wait until the simulated time has moved on by ``seconds``."""
        target = self.seconds() + seconds
        while self.seconds() < target:
            time.sleep(POLL_S)
