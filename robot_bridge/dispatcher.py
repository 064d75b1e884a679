"""The dispatcher: gate, then send time-parameterized segments to the controller and follow them.

Nothing is published on ``cmd/trajectory`` unless the safety gate passed the very
plan being sent, against the approved hash and the robot's measured state.
Segments (<= 1 s of points each) go out with ``seq``, ``job_id`` and
``plan_sha256`` at real-time priority, express, drop on congestion, a few
segments ahead of the controller's progress. The controller is watched two ways:
its liveliness token (gone when its session dies) and an application heartbeat
(a frozen controller keeps its token until the lease ends). Losing either aborts
the job and sends a stop within the watchdog timeout.

Every command is signed with the dispatcher's Ed25519 key and carries
``expires_at`` (``robot_bridge.signing``); without a key nothing is dispatched.
While an execution runs, a dedicated thread publishes the dispatcher's own
heartbeat on ``cmd/heartbeat`` (every ``heartbeat_period_s``, its own ``seq``):
the controller's dead-man, so a dispatcher that dies or a link that breaks
stops the robot on the controller's side too. When an execution was aborted
because the controller was lost, the stop is sent again as soon as that
controller is heard from again, and reported through ``on_controller_return``.

The service calls :meth:`Dispatcher.execute` from a worker thread and gets every
step through ``on_event(kind, data)``: ``gate``, ``dispatching``, ``segment``,
``executing``, ``robot_state``, ``controller``, ``stop_sent``, ``finished``.
"""

from __future__ import annotations

import threading
import time
from datetime import datetime
from typing import Any, Callable

from schemas.bridge import JointState, TrajectorySegment
from schemas.policy import SafetyPolicy

from .dispatch_io import DispatcherIO
from .dispatch_run import Execution, _Run
from .dispatch_types import (
    BusyError,
    ControllerUnavailableError,
    DispatchSettings,
    EventCallback,
    ExecutionResult,
    NoSigningKeyError,
    SignedSegment,
    split_segments,
)
from .dispatch_watch import ControllerWatch, HeartbeatSender, LossWatch
from .gate import Approval, MeasuredState, SafetyGate
from .settings import BridgeSettings, Keys
from .signing import Signer

#: The dispatcher's parts live in robot_bridge.dispatch_* modules; these names stay importable from here.
__all__ = ["BusyError", "ControllerUnavailableError", "Dispatcher", "DispatchSettings", "EventCallback",
           "ExecutionResult", "NoSigningKeyError", "SignedSegment", "split_segments",
           "wait_for_controller"]


class Dispatcher:
    """One zenoh peer of the bridge for one robot; thread-safe, one execution at a time.

    Its parts: the zenoh I/O (:class:`~robot_bridge.dispatch_io.DispatcherIO`), the controller watch and the
    dispatcher's own heartbeat (:mod:`robot_bridge.dispatch_watch`), and the execution state machine
    (:class:`~robot_bridge.dispatch_run.Execution`); this class gates a plan and hands it to them."""

    def __init__(self, settings: BridgeSettings | None = None, dispatch: DispatchSettings | None = None,
                 gate: SafetyGate | None = None, signer: Signer | None = None,
                 on_controller_return: Callable[[str, dict[str, Any]], None] | None = None,
                 policy: SafetyPolicy | None = None):
        self.settings = settings or BridgeSettings()
        self.dispatch = dispatch or DispatchSettings()
        if signer is None and self.settings.signing_key is not None:
            signer = Signer.from_file(self.settings.signing_key)
        self.signer = signer
        #: Called (job_id, data) from a zenoh thread when a controller lost during that job is heard from again
        #: and the stop was sent again.
        self.on_controller_return = on_controller_return
        # The gate holds the site's safety policy (its floor, caps and hash); the start tolerance comes with each
        # measured state (see _execute).
        self.gate = gate or SafetyGate(policy=policy)
        self.keys = Keys(self.settings.robot_id)
        self._lock = threading.Lock()
        self._run_lock = threading.Lock()
        self._stop_requests: set[str | None] = set()
        # seq must grow across jobs and restarts of this process: start from the clock (ms)
        self._seq = int(time.time() * 1000)
        self._io = DispatcherIO(self.settings, signer)
        self._watch = ControllerWatch(self.settings, self.dispatch.state_max_age_s, self.keys.alive, self._controller_back)
        self._heartbeat = HeartbeatSender(self.settings, self._io)
        d = self.dispatch
        self._loss = LossWatch(self.settings, d.self_stall_s, d.resync_s, d.poll_period_s, self._watch, self._heartbeat,
                               self._io)
        self._execution = Execution(self.settings, self.dispatch, self._io, self._watch, self._heartbeat, self._loss, signer,
                                    self._stop_requested, self._publish_segment, self._begin_heartbeat)
        self._io.subscribe(self._watch.on_alive, self._watch.on_heartbeat, self._watch.on_joints, self._watch.on_exec)

    @property
    def _pub_traj(self) -> Any:
        return self._io.pub_traj

    @property
    def _pub_stop(self) -> Any:
        return self._io.pub_stop

    def _publish_segment(self, seg: TrajectorySegment) -> None:
        """Put one segment of the running execution on ``cmd/trajectory`` (a seam for fault injection)."""
        self._execution.put_segment(seg)

    def _begin_heartbeat(self, job_id: str) -> None:
        """Start the dispatcher's heartbeat for ``job_id`` (a seam for fault injection)."""
        self._heartbeat.begin(job_id)

    def _end_heartbeat(self) -> None:
        """Stop the dispatcher's heartbeat (the controller's dead-man then stops the robot)."""
        self._heartbeat.end()

    def _controller_back(self, how: str) -> None:
        """A controller is heard from while jobs aborted for its loss are unconfirmed: send their stops again."""
        for job_id, info in self._watch.take_lost().items():
            reason = f"stop re-sent: the controller lost during job {job_id} is back ({how})"
            sent_at = self._io.send_stop(job_id, reason)
            data = {"job_id": job_id, "reason": reason, "sent_at": sent_at, "aborted_for": info.get("reason"),
                    "lost_for_s": time.monotonic() - info["at"]}
            callback = self.on_controller_return
            if callback is not None:
                try:
                    callback(job_id, data)
                except Exception:  # noqa: BLE001 - a failing recorder must not stop the re-send of others
                    pass

    # ------------------------------------------------------------------ status
    def zid(self) -> str:
        """This peer's zenoh id (for diagnostics and tests)."""
        return self._io.zid()

    def controller_problem(self, since: float | None = None) -> str | None:
        """Why the controller is not usable now, or None when it is alive (token and fresh heartbeat).

        ``since``: judge the heartbeat's age from no earlier than this (``time.monotonic()``)."""
        return self._watch.controller_problem(since)

    def last_heartbeat_at(self) -> float | None:
        """``time.monotonic()`` of the last heartbeat received, or None."""
        return self._watch.last_heartbeat_at()

    def controller_alive(self) -> bool:
        return self.controller_problem() is None

    def wait_for_controller(self, timeout_s: float) -> bool:
        """Wait (bounded) until a controller is alive and its joint state is known."""
        return wait_for_controller(self, timeout_s)

    def measured_state(self) -> JointState | None:
        """The latest joint state, or None when none arrived within ``state_max_age_s``."""
        return self._watch.measured_state()

    # ------------------------------------------------------------------ commands
    def stop(self, job_id: str | None = None, reason: str = "stop requested by operator") -> float:
        """Publish ``cmd/stop`` now (repeated a few times); a running execution of that job ends aborted.

        Returns the ``time.monotonic()`` at which the first stop was published."""
        with self._lock:
            self._stop_requests.add(job_id)
        return self._io.send_stop(job_id, reason)

    def _stop_requested(self, job_id: str) -> bool:
        with self._lock:
            return job_id in self._stop_requests or None in self._stop_requests

    def _next_seq(self, count: int) -> int:
        with self._lock:
            first = self._seq
            self._seq += count
        return first

    # ------------------------------------------------------------------ execution
    def execute(self, plan: dict[str, Any] | str | bytes, *, job_id: str, approved_sha256: str, approval_expires_at: datetime,
                threshold_m: float | None = None, on_event: EventCallback | None = None,
                stop_event: threading.Event | None = None, recovery: bool = False,
                physics: dict[str, Any] | None = None) -> ExecutionResult:
        """Gate the plan, send it, follow it to the end.

        ``plan`` is the plan dict, or its canonical JSON text or bytes (``schemas.plan.canonical_json``):
        the bytes are hashed as they are, which saves about a second on a 60 s plan.

        Raises :class:`NoSigningKeyError` without a signing key, :class:`ControllerUnavailableError`
        before anything happens when no controller is alive or its state is unknown (the job stays
        approved), and :class:`BusyError` when another execution runs. ``recovery``: the plan is a
        recover job's (the gate's margin floor is then its start where that is under the threshold). ``physics``:
        the plan's physics dry run (``regrasp.simreport/1``, bound to its hash), judged by the gate when the safety
        policy requires one.
        """
        if self.signer is None:
            raise NoSigningKeyError("the bridge has no signing key (REGRASP_BRIDGE_SIGNING_KEY): a controller refuses "
                                    "unsigned commands, so nothing is dispatched; make a pair with "
                                    "'regrasp keys generate DIR'")
        if not self._run_lock.acquire(blocking=False):
            raise BusyError("another execution is running on this dispatcher")
        try:
            return self._execute(plan, job_id, approved_sha256, approval_expires_at, threshold_m, on_event or (lambda k, d: None),
                                 stop_event or threading.Event(), recovery, physics)
        finally:
            self._run_lock.release()

    def _execute(self, plan: dict[str, Any] | str | bytes, job_id: str, approved_sha256: str, expires_at: datetime,
                 threshold_m: float | None, emit: EventCallback, stop_event: threading.Event,
                 recovery: bool = False, physics: dict[str, Any] | None = None) -> ExecutionResult:
        started = time.monotonic()
        if self._watch.token_alive():
            self.wait_for_controller(self.dispatch.state_wait_s)
        problem = self.controller_problem()
        state = self.measured_state()
        if problem is not None:
            raise ControllerUnavailableError(problem)
        if state is None:
            raise ControllerUnavailableError("the controller's joint state is unknown (no recent state/joints)")
        with self._lock:
            self._stop_requests.discard(job_id)
            self._stop_requests.discard(None)
        approval = Approval(approved_sha256, expires_at)
        measured = MeasuredState(state.joint_names, state.q, self.dispatch.start_tolerance_rad)
        if isinstance(plan, (bytes, bytearray, str)):
            verdict, parsed = self.gate.check_json(plan, approval=approval, measured=measured, threshold_m=threshold_m,
                                                   recovery=recovery, physics=physics)
            plan = parsed if parsed is not None else {}  # None only with a veto (the plan is not read on)
        else:
            verdict = self.gate.check(plan, approval=approval, measured=measured, threshold_m=threshold_m,
                                      recovery=recovery, physics=physics)
        emit("gate", verdict.model_dump(mode="json"))
        if not verdict.passed:
            return ExecutionResult("rejected", verdict.summary(), verdict, duration_s=time.monotonic() - started)
        # Only the gate-passed, hash-checked plan is cut into segments, right now.
        segments = split_segments(plan, job_id, verdict.plan_sha256 or approved_sha256, 0, self.dispatch.segment_duration_s)
        first_seq = self._next_seq(len(segments))
        for seg in segments:
            seg.seq += first_seq
        n_points = sum(len(seg.points) for seg in segments)
        emit("dispatching", {"job_id": job_id, "segments": len(segments), "points": n_points, "dt_s": segments[0].dt_s,
                             "plan_sha256": verdict.plan_sha256, "first_seq": segments[0].seq})
        self._watch.drain_exec()
        run = _Run(job_id=job_id, segments=segments, seqs=frozenset(seg.seq for seg in segments))
        self._watch.forget_lost(job_id)
        return self._execution.run(run, emit, stop_event, verdict, started)

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        if self._io.session is None:
            return
        self._loss.close()
        self._heartbeat.close()
        self._io.close()

    def __enter__(self) -> "Dispatcher":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def wait_for_controller(bridge: Any, timeout_s: float) -> bool:
    """Wait (bounded) until ``bridge`` (a dispatcher or its process proxy) sees a live controller whose
    joint state is known."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if bridge.controller_alive() and bridge.measured_state() is not None:
            return True
        time.sleep(0.01)
    return False
