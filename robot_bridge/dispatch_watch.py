"""The dispatcher's heartbeat and its watch on the controller.

Part of the dispatcher (:mod:`robot_bridge.dispatcher`). Two directions:

- :class:`ControllerWatch` follows the controller: its liveliness token (gone when its session dies), its
  application heartbeat (a frozen controller keeps its token until the lease ends), its joint state and its
  exec status (queued for the execution state machine). A job aborted because its controller was lost is
  remembered; when that controller is heard from again its stop is sent again (``on_back``).
- :class:`HeartbeatSender` publishes the dispatcher's own heartbeat on ``cmd/heartbeat`` while an execution
  runs, from a thread that does nothing else: the controller's dead-man, so a dispatcher that dies or a link
  that breaks stops the robot on the controller's side too.
"""

from __future__ import annotations

import collections
import math
import queue
import threading
import time
from typing import Any, Callable

import zenoh
from pydantic import ValidationError

from schemas.bridge import ExecStatus, Heartbeat, JointState

from .dispatch_io import DispatcherIO
from .process_tuning import raise_thread_priority, use_realtime_scheduling
from .settings import BridgeSettings

#: Measured states kept between two ``robot_state`` events at most (a 2 kHz controller for 5 s).
MEASURED_KEPT = 10_000


class ControllerWatch:
    """What the dispatcher knows of the controller; its callbacks run on zenoh's threads."""

    def __init__(self, settings: BridgeSettings, state_max_age_s: float, alive_key: str,
                 on_back: Callable[[str], None]):
        self.settings = settings
        self.state_max_age_s = state_max_age_s
        self.alive_key = alive_key
        #: Called with how the controller was heard from, while jobs aborted for its loss are unconfirmed.
        self.on_back = on_back
        self._lock = threading.Lock()
        self._token_alive = False
        self._last_heartbeat: float | None = None
        self._beat: Heartbeat | None = None  # the last heartbeat's content (the controller's state and its job)
        self._joint_state: JointState | None = None
        self._joint_state_at: float | None = None
        #: Every measured state received since the last ``take_measured()`` (while one is collecting), in order.
        self._measured: collections.deque[JointState] = collections.deque(maxlen=MEASURED_KEPT)
        self._collecting = False
        #: (receipt time, status) of every ``state/exec`` message, for the running execution.
        self.exec: queue.Queue = queue.Queue()
        self._lost: dict[str, dict[str, Any]] = {}  # job id -> why it was aborted, while its controller is away

    # ------------------------------------------------------------------ zenoh callbacks
    def on_alive(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._token_alive = sample.kind == zenoh.SampleKind.PUT
        if sample.kind == zenoh.SampleKind.PUT:
            self._back("liveliness token")

    def on_heartbeat(self, sample: zenoh.Sample) -> None:
        try:
            beat = Heartbeat.model_validate_json(sample.payload.to_bytes())  # only a well-formed heartbeat counts
        except ValidationError:
            return
        with self._lock:
            self._last_heartbeat = time.monotonic()
            self._beat = beat
            lost = bool(self._lost)
        if lost:
            self._back("heartbeat")

    def on_joints(self, sample: zenoh.Sample) -> None:
        try:
            js = JointState.model_validate_json(sample.payload.to_bytes())
        except ValidationError:
            return
        with self._lock:
            self._joint_state, self._joint_state_at = js, time.monotonic()
            if self._collecting:
                self._measured.append(js)

    def on_exec(self, sample: zenoh.Sample) -> None:
        try:
            self.exec.put((time.monotonic(), ExecStatus.model_validate_json(sample.payload.to_bytes())))
        except ValidationError:
            pass

    def _back(self, how: str) -> None:
        with self._lock:
            lost = bool(self._lost)
        if lost:
            self.on_back(how)

    # ------------------------------------------------------------------ measured states
    def collect_measured(self, on: bool) -> None:
        """Keep every measured state from now on (an execution's, for its ``robot_state`` batches), or stop."""
        with self._lock:
            self._collecting = on
            self._measured.clear()

    def take_measured(self) -> list[JointState]:
        """The measured states received since the last call (oldest first), forgotten from now on."""
        with self._lock:
            taken = list(self._measured)
            self._measured.clear()
        return taken

    # ------------------------------------------------------------------ lost jobs
    def mark_lost(self, job_id: str, reason: str) -> None:
        """``job_id`` was aborted because its controller was lost: its stop goes again when it is back."""
        with self._lock:
            self._lost[job_id] = {"reason": reason, "at": time.monotonic()}

    def forget_lost(self, job_id: str) -> None:
        with self._lock:
            self._lost.pop(job_id, None)

    def take_lost(self) -> dict[str, dict[str, Any]]:
        """The jobs lost with their controller (each ``{"reason", "at"}``), forgotten from now on."""
        with self._lock:
            lost, self._lost = self._lost, {}
        return lost

    # ------------------------------------------------------------------ status
    def token_alive(self) -> bool:
        with self._lock:
            return self._token_alive

    def controller_problem(self, since: float | None = None) -> str | None:
        """Why the controller is not usable now, or None when it is alive (token and fresh heartbeat).

        ``since``: judge the heartbeat's age from no earlier than this (``time.monotonic()``): the moment this
        process could run again after it was itself held up, when the heartbeats that came meanwhile were
        still waiting for its interpreter."""
        with self._lock:
            token, beat = self._token_alive, self._last_heartbeat
        if not token:
            return f"no controller: liveliness token {self.alive_key} is absent"
        if beat is None:
            return "no controller heartbeat received yet"
        age = time.monotonic() - (beat if since is None else max(beat, since))
        if age > self.settings.watchdog_timeout_s:
            return (f"controller heartbeat lost: none for {age * 1000:.0f} ms "
                    f"(watchdog {self.settings.watchdog_timeout_s * 1000:.0f} ms)")
        return None

    def controller_ended(self, job_id: str, since: float) -> tuple[str, str] | None:
        """``(status, reason)`` when the controller's heartbeat, received after ``since`` (``time.monotonic()``),
        says it holds after ending ``job_id`` (its own stop, a fault); else None.

        The controller's truth when its ``state/exec`` report was missed: by a dispatcher frozen while the
        controller stopped, whose link was dropped and made again meanwhile."""
        with self._lock:
            beat, at = self._beat, self._last_heartbeat
        if beat is None or at is None or at < since or beat.job_id != job_id or beat.state != "holding":
            return None
        return beat.status or "stopped", beat.reason or "the controller's heartbeat says it ended the job and holds"

    def last_heartbeat_at(self) -> float | None:
        with self._lock:
            return self._last_heartbeat

    def measured_state(self) -> JointState | None:
        """The latest joint state, or None when none arrived within ``state_max_age_s``."""
        with self._lock:
            js, at = self._joint_state, self._joint_state_at
        if js is None or at is None or time.monotonic() - at > self.state_max_age_s:
            return None
        return js

    def drain_exec(self) -> None:
        """Forget the exec statuses received so far (an execution starts)."""
        while True:
            try:
                self.exec.get_nowait()
            except queue.Empty:
                return


class HeartbeatSender:
    """The dispatcher's heartbeat on ``cmd/heartbeat`` (every ``heartbeat_period_s``, its own ``seq`` per job)."""

    def __init__(self, settings: BridgeSettings, io: DispatcherIO):
        self.settings = settings
        self.io = io
        self._lock = threading.Lock()
        self._job: str | None = None  # the execution whose heartbeat runs
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="bridge-heartbeat", daemon=True)
        self._thread.start()

    def begin(self, job_id: str) -> None:
        """Start beating for ``job_id`` (the controller arms its dead-man at the job's first segment)."""
        with self._lock:
            self._job = job_id
        self._wake.set()

    def end(self) -> None:
        """Stop beating: without it the controller's dead-man stops the robot."""
        with self._lock:
            self._job = None

    def _loop(self) -> None:
        """A small signed message every period and nothing else on this thread (no events, no locks held across
        a send), at the bridge's thread priority (real-time where allowed)."""
        raise_thread_priority(self.settings.thread_nice)
        use_realtime_scheduling(self.settings.realtime_priority)
        period = self.settings.heartbeat_period_s
        job, seq = None, 0
        next_at = time.monotonic()
        while not self._closing.is_set():
            with self._lock:
                current = self._job
            if current is None:
                job = None
                self._wake.wait(0.5)
                self._wake.clear()
                next_at = time.monotonic()
                continue
            if current != job:
                job, seq = current, 0
            now_unix = time.time()
            msg = {"job_id": job, "seq": seq, "t": now_unix, "expires_at": now_unix + self.settings.heartbeat_expiry_s}
            try:
                self.io.put_heartbeat(msg)
            except Exception:  # noqa: BLE001 - a closed session ends the loop below
                if self._closing.is_set():
                    return
            seq += 1
            next_at += period
            delay = next_at - time.monotonic()
            if delay <= 0:
                next_at = time.monotonic()  # late: the next one goes now, no burst to catch up
                continue
            self._wake.wait(delay)
            self._wake.clear()

    def close(self) -> None:
        self._closing.set()
        self._wake.set()
        self._thread.join(timeout=1.0)


class LossWatch:
    """Judges, on a thread of its own, whether the controller of the running execution is lost, and acts at once.

    A lost controller (its liveliness token gone, or no heartbeat for the watchdog) is noticed here, not in the
    execution loop: that loop also sends segments, signs, and hands every event to the service, and a slow
    event consumer or a busy interpreter must not delay the stop. On a loss this thread ends the dispatcher's
    heartbeat (so the controller's dead-man stops the robot even if the stop is lost), sends the stop, records
    the job as lost with its controller, reports ``stop_sent`` and lets the execution loop end the job.

    Its own stalls are allowed for, as the loop's were: after this thread could not run for ``self_stall_s``,
    the heartbeat's age counts from when it runs again; after a freeze longer than the watchdog (the
    controller's dead-man has stopped the robot, the link may have been dropped and made again), the
    controller is given ``resync_s`` to be heard from before it is judged lost.
    """

    def __init__(self, settings: BridgeSettings, self_stall_s: float, resync_s: float, poll_s: float,
                 watch: ControllerWatch, heartbeat: HeartbeatSender, io: DispatcherIO):
        self.settings = settings
        self.self_stall_s, self.resync_s, self.poll_s = self_stall_s, resync_s, poll_s
        self.watch, self.heartbeat, self.io = watch, heartbeat, io
        self._lock = threading.Lock()
        self._job: str | None = None
        self._emit: Callable[[str, dict[str, Any]], None] | None = None
        self._lost: tuple[str, float] | None = None
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="bridge-loss-watch", daemon=True)
        self._thread.start()

    def arm(self, job_id: str, emit: Callable[[str, dict[str, Any]], None]) -> None:
        """Watch the controller for ``job_id`` from now on (its segments are about to go out)."""
        with self._lock:
            self._job, self._emit, self._lost = job_id, emit, None
        self._wake.set()

    def disarm(self) -> tuple[str, float] | None:
        """Stop watching; returns ``(reason, stop sent at)`` when the watch had found the controller lost. Once it
        returns, this thread sends and reports nothing more for the job."""
        with self._lock:
            self._job, self._emit = None, None
            return self._lost

    def lost(self) -> tuple[str, float] | None:
        """``(reason, stop sent at)`` once the controller of the armed job was found lost, else None."""
        with self._lock:
            return self._lost

    def _loop(self) -> None:
        raise_thread_priority(self.settings.thread_nice)
        use_realtime_scheduling(self.settings.realtime_priority)
        job: str | None = None
        last = resumed_at = time.monotonic()
        resync_until = -math.inf
        while not self._closing.is_set():
            with self._lock:
                current = self._job if self._lost is None else None
            tick = time.monotonic()
            if current != job:  # armed for another job, or disarmed: judge from now
                job, last, resumed_at, resync_until = current, tick, tick, -math.inf
            if current is None:
                self._wake.wait(0.5)
                self._wake.clear()
                continue
            gap = tick - last
            if gap > self.self_stall_s:
                if gap > self.settings.watchdog_timeout_s:
                    resync_until = tick + self.resync_s
                resumed_at = tick
            last = tick
            problem = self.watch.controller_problem(since=resumed_at)
            if problem is not None and tick >= resync_until:
                self._act(job, f"controller lost: {problem}")
            self._wake.wait(self.poll_s)

    def _act(self, job_id: str, reason: str) -> None:
        with self._lock:  # held while acting: a disarm waits for the stop and its report
            if self._job != job_id or self._lost is not None:
                return
            # The heartbeat ends first: should the stop not arrive, the controller's dead-man stops the robot.
            self.heartbeat.end()
            self.watch.mark_lost(job_id, reason)
            sent_at = self.io.send_stop(job_id, reason)
            # Reported before the execution loop can see the loss, so the job's events stay in order.
            if self._emit is not None:
                try:
                    self._emit("stop_sent", {"job_id": job_id, "reason": reason, "sent_at": sent_at})
                except Exception:  # noqa: BLE001 - a failing recorder must not hide the loss from the loop
                    pass
            self._lost = (reason, sent_at)

    def close(self) -> None:
        self._closing.set()
        self._wake.set()
        self._thread.join(timeout=1.0)
