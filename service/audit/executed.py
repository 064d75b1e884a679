"""The execution's timeline: the controller's clock on the file's, and the plan replayed on it.

The controller stamps each measured joint state with its own monotonic clock (seconds). The
first measured state of an execution fixes the offset between that clock and the file's
(Unix ns): the time the service recorded that state's report. Every later measurement is
placed by the controller's own stamp, so the intervals between measurements are the
controller's, and a robot message's ``publish_time`` is its measurement time.

The plan's playback is published again under ``/executed_plan/`` on that timeline: the
first segment starts where the controller's reported index and its speed (plan time per
second of its clock, from the first two distinct indices) put plan time zero, and each
playback sample is written once the controller has reached it. So in Foxglove the planned
and the measured robot move together, and after an abort the replayed plan stops where the
robot stopped.
"""

from __future__ import annotations

from typing import Any, Mapping

from .playback import EXECUTED_PLAN_TOPICS, Message, Playback
from .topics import NS_PER_S


class ControllerClock:
    """The controller's clock (s) mapped onto the file's (Unix ns), fixed at the first measurement."""

    def __init__(self) -> None:
        self.offset_ns: int | None = None

    def to_ns(self, stamp_s: float, reported_ns: int) -> int:
        """The file time of a measurement stamped ``stamp_s`` whose report was recorded at ``reported_ns``."""
        own = int(round(float(stamp_s) * NS_PER_S))
        if self.offset_ns is None:
            self.offset_ns = reported_ns - own
        return own + self.offset_ns


class ExecutedPlan:
    """The plan's playback stamped on the execution's timeline as the controller reports its progress."""

    def __init__(self, playback: Playback) -> None:
        self.playback = playback
        trajectory = playback.plan.get("trajectory") or []
        self._t = [float(p.get("t", i * playback.dt)) for i, p in enumerate(trajectory)]
        self._anchor: tuple[float, int] | None = None  # (plan time, file ns) of the last state at the first index
        self._speed: float | None = None  # plan seconds per second of the controller's clock
        self._next = 0  # next playback sample to write
        self._static_done = False

    @property
    def speed(self) -> float | None:
        return self._speed

    def advance(self, index: int, ns: int) -> list[Message]:
        """The controller measured trajectory ``index`` at file time ``ns``: the playback samples reached so far."""
        if not self._t or index < 0:
            return []
        t = self._t[min(index, len(self._t) - 1)]
        if self._speed is None:
            if self._anchor is None or t <= self._anchor[0]:
                self._anchor = (t, ns)  # still at the first index (a start buffer holds it): keep the latest
                return []
            t0, ns0 = self._anchor
            if ns <= ns0:
                return []
            self._speed = (t - t0) / ((ns - ns0) / NS_PER_S)
        t0, ns0 = self._anchor  # type: ignore[misc]
        start_ns = ns0 - int(round(t0 / self._speed * NS_PER_S))
        out: list[Message] = []
        if not self._static_done:
            out += list(self.playback.static(start_ns, EXECUTED_PLAN_TOPICS))
            self._static_done = True
        pb = self.playback
        while self._next < len(pb.indices) and pb.indices[self._next] <= index:
            k = self._next
            out += list(pb.sample(k, start_ns + int(round(pb.t_of(k) / self._speed * NS_PER_S)), EXECUTED_PLAN_TOPICS))
            self._next += 1
        return out


def measured_samples(payload: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Measured joint states an event carries, each ``{stamp, q, index}`` (one, or a batch under ``samples``)."""
    data = payload.get("data") if isinstance(payload.get("data"), Mapping) else payload
    if not isinstance(data, Mapping):
        return []
    batch = data.get("samples")
    if isinstance(batch, list):
        return [s for s in batch if isinstance(s, Mapping) and isinstance(s.get("stamp"), (int, float))]
    if isinstance(data.get("stamp"), (int, float)) and data.get("q") is not None:
        return [{"stamp": data["stamp"], "q": data["q"], "index": data.get("index")}]
    return []
