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

import math
import queue
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Callable, Literal

import zenoh
from pydantic import Field, ValidationError
from pydantic_settings import BaseSettings, SettingsConfigDict

from schemas.bridge import (
    MAX_SEGMENT_DURATION_S,
    ExecStatus,
    GateVerdict,
    Heartbeat,
    JointState,
    Stop,
    TrajectorySegment,
)

from .gate import Approval, ExecutablePlan, MeasuredState, SafetyGate
from .process_tuning import raise_thread_priority
from .settings import BridgeSettings, Keys
from .signing import Signer, canonical_bytes
from .zenoh_session import control_publisher, open_session

EventCallback = Callable[[str, dict[str, Any]], None]


class DispatchSettings(BaseSettings):
    """Pacing and deadlines of one execution (environment prefix ``REGRASP_DISPATCH_``).

    The lookahead is counted in trajectory time; a controller that plays faster than
    real time (the simulator's ``--speed``) needs proportionally more segments ahead.
    """

    model_config = SettingsConfigDict(env_prefix="REGRASP_DISPATCH_", frozen=True, extra="forbid")

    segment_duration_s: float = Field(0.25, gt=0, le=MAX_SEGMENT_DURATION_S,
                                      description="time spanned by one segment's points (the contract allows 1 s; "
                                                  "0.25 s keeps a segment near 20 KB, so it crosses in about a millisecond)")
    lookahead_segments: int = Field(8, ge=1, le=1000, description="segments sent ahead of the one being played (2 s)")
    max_in_flight_segments: int = Field(
        2, ge=1, le=1000,
        description="segments sent but not yet acknowledged, at most: the lookahead fills one acknowledgement (about a "
                    "millisecond) at a time instead of in one burst, whose later segments queued behind the earlier ones "
                    "in the controller's receive path (up to 3 ms for the 9-segment burst of a job's start)",
    )
    in_flight_wait_s: float = Field(
        0.01, gt=0, le=1.0,
        description="once the oldest unacknowledged segment is this old, one more segment goes out every this often "
                    "whatever the window: a late acknowledgement (a stalled peer, a lost segment) must not starve a "
                    "controller that plays the two segments it has in 50 ms (0.25 s segments at 10x), and the lookahead "
                    "must not go out in one burst either (80 segments at 10x overflowed zenoh's transmit queue, whose "
                    "drop-on-congestion then lost segments)",
    )
    poll_period_s: float = Field(0.005, gt=0, le=0.1, description="how often the execution loop looks at its inputs")
    self_stall_s: float = Field(
        0.05, gt=0, le=1.0,
        description="an execution loop that did not run for this long was itself held up (its process starved of the "
                    "CPU or the interpreter): the heartbeat watchdog then counts from when it runs again, since the "
                    "controller's heartbeats that came meanwhile were waiting for the same interpreter. The robot is "
                    "still covered meanwhile: the controller's own dead-man stops it if this process goes quiet")
    progress_timeout_s: float = Field(3.0, gt=0, description="no progress report for this long = fault")
    resend_after_s: float = Field(0.1, gt=0, description="re-send a segment the controller has not acknowledged by then")
    gap_holdoff_s: float = Field(
        0.02, gt=0, le=1.0,
        description="when the controller refuses a segment for a gap before it, the missing one and those behind it are "
                    "re-sent at once (not after resend_after_s: a fast-playing controller has less than that buffered "
                    "at a job's start); refusals within this time after such a re-send are of copies already on their "
                    "way and start no other",
    )
    max_resends: int = Field(5, ge=0, le=100, description="re-sends of the oldest unacknowledged segment (the controller "
                                                           "drops duplicates); the ones behind it go with it for free")
    ack_timeout_s: float = Field(1.0, gt=0, description="wait for the controller to acknowledge a stop")
    robot_state_event_period_s: float = Field(0.1, gt=0, description="rate of 'robot_state' events (for the audit)")
    state_max_age_s: float = Field(0.5, gt=0, description="a measured state older than this is not used by the gate")
    state_wait_s: float = Field(
        1.0, ge=0, le=10.0,
        description="when a dispatch starts while the controller's token is present but its heartbeat or joint state is "
                    "not fresh, wait this long for fresh ones before refusing: a host that paused the bridge's process "
                    "(a VM's steal, a long collection) leaves both stale for a moment although the controller is fine",
    )
    start_tolerance_rad: float = Field(0.01, gt=0, description="first point vs measured state (sent with each measured "
                                                                 "state: it overrides the gate's own setting)")


class ControllerUnavailableError(RuntimeError):
    """No controller is alive, or its state is unknown: nothing was started (HTTP 409)."""


class BusyError(RuntimeError):
    """Another execution is running on this dispatcher."""


class NoSigningKeyError(RuntimeError):
    """The dispatcher has no signing key: the controller would refuse every command, so nothing is sent (HTTP 409)."""


class SignedSegment:
    """One segment's canonical JSON, split around its ``expires_at`` so that a send only adds the expiry and signs.

    Keys sort ``dt_s``, ``expires_at``, ...: the canonical bytes are ``prefix + repr(expires_at) + suffix``."""

    __slots__ = ("seq", "prefix", "suffix")

    def __init__(self, seg: TrajectorySegment):
        doc = seg.model_dump(mode="json", exclude={"sig"})
        doc["expires_at"] = 0.0
        body = canonical_bytes(doc)
        marker = b'"expires_at":0.0,'
        i = body.index(marker) + len(b'"expires_at":')
        self.seq = seg.seq
        self.prefix, self.suffix = body[:i], body[i + len(b"0.0"):]

    def wire(self, signer: Signer, expires_at: float) -> bytes:
        body = self.prefix + repr(float(expires_at)).encode() + self.suffix
        return body[:-1] + b',"sig":"' + signer.signature(body).encode("ascii") + b'"}'


@dataclass
class ExecutionResult:
    """How an execution ended: ``succeeded``, ``aborted`` (stopped, lost, fault) or ``rejected`` (gate veto)."""

    status: Literal["succeeded", "aborted", "rejected"]
    reason: str
    verdict: GateVerdict | None = None
    last_index: int | None = None
    segments_sent: int = 0
    duration_s: float = 0.0
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"status": self.status, "reason": self.reason, "verdict": self.verdict.model_dump(mode="json") if self.verdict else None,
                "last_index": self.last_index, "segments_sent": self.segments_sent, "duration_s": self.duration_s,
                "details": self.details}


def split_segments(plan: dict[str, Any] | ExecutablePlan, job_id: str, plan_sha256: str, first_seq: int,
                   segment_duration_s: float = MAX_SEGMENT_DURATION_S) -> list[TrajectorySegment]:
    """The plan's trajectory cut into consecutive segments of at most ``segment_duration_s``.

    ``plan`` is a plan document or the fields the gate decoded from its bytes (:class:`ExecutablePlan`)."""
    if isinstance(plan, ExecutablePlan):
        dt, names = float(plan.dt_s), list(plan.robot.joint_names)
        qs, holding = [p.q for p in plan.trajectory], [p.holding for p in plan.trajectory]
    else:
        dt, names = float(plan["dt_s"]), list(plan["robot"]["joint_names"])
        qs, holding = [p["q"] for p in plan["trajectory"]], [p["holding"] for p in plan["trajectory"]]
    per = max(1, int(math.floor(segment_duration_s / dt + 1e-9)) + 1)  # points spanning at most the duration
    starts = list(range(0, len(qs), per))
    return [
        TrajectorySegment(
            job_id=job_id, plan_sha256=plan_sha256, seq=first_seq + k, segment_index=k, segment_count=len(starts),
            joint_names=names, dt_s=dt, t_from_start=start * dt, first_index=start,
            points=qs[start:start + per], holding=holding[start:start + per],
        )
        for k, start in enumerate(starts)
    ]


class Dispatcher:
    """One zenoh peer of the bridge for one robot; thread-safe, one execution at a time."""

    def __init__(self, settings: BridgeSettings | None = None, dispatch: DispatchSettings | None = None,
                 gate: SafetyGate | None = None, signer: Signer | None = None,
                 on_controller_return: Callable[[str, dict[str, Any]], None] | None = None):
        self.settings = settings or BridgeSettings()
        self.dispatch = dispatch or DispatchSettings()
        if signer is None and self.settings.signing_key is not None:
            signer = Signer.from_file(self.settings.signing_key)
        self.signer = signer
        #: Called (job_id, data) from a zenoh thread when a controller lost during that job is heard from again
        #: and the stop was sent again.
        self.on_controller_return = on_controller_return
        self.gate = gate or SafetyGate()  # the start tolerance comes with each measured state (see _execute)
        self.keys = Keys(self.settings.robot_id)
        self._lock = threading.Lock()
        self._run_lock = threading.Lock()
        self._token_alive = False
        self._last_heartbeat: float | None = None
        self._joint_state: JointState | None = None
        self._joint_state_at: float | None = None
        self._exec: queue.Queue = queue.Queue()
        self._stop_requests: set[str | None] = set()
        # seq must grow across jobs and restarts of this process: start from the clock (ms)
        self._seq = int(time.time() * 1000)
        self._payloads: dict[int, SignedSegment] = {}  # seq -> segment ready to sign, of the running execution only
        self._lost: dict[str, dict[str, Any]] = {}  # job id -> why it was aborted, while its controller is away
        self._heartbeat_job: str | None = None  # the execution whose heartbeat runs
        self._heartbeat_wake = threading.Event()
        self._closing = threading.Event()
        # zenoh's runtime threads start with the session and inherit this thread's priority for their lives;
        # the calling thread gets its own back afterwards.
        before = _thread_nice()
        raised = raise_thread_priority(self.settings.thread_nice)
        try:
            self._session = open_session(self.settings)
        finally:
            if raised and before is not None:
                raise_thread_priority(before)
        s = self._session
        self._pub_traj = control_publisher(s, self.keys.trajectory)
        self._pub_stop = control_publisher(s, self.keys.stop)
        self._pub_heartbeat = control_publisher(s, self.keys.command_heartbeat)
        self._heartbeat_thread = threading.Thread(target=self._heartbeat_loop, name="bridge-heartbeat", daemon=True)
        self._heartbeat_thread.start()
        self._subs = [
            s.liveliness().declare_subscriber(self.keys.alive, self._on_alive, history=True),
            s.declare_subscriber(self.keys.heartbeat, self._on_heartbeat),
            s.declare_subscriber(self.keys.joints, self._on_joints),
            s.declare_subscriber(self.keys.exec, self._on_exec),
        ]

    # ------------------------------------------------------------------ telemetry callbacks (zenoh threads)
    def _on_alive(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._token_alive = sample.kind == zenoh.SampleKind.PUT
        if sample.kind == zenoh.SampleKind.PUT:
            self._controller_back("liveliness token")

    def _on_heartbeat(self, sample: zenoh.Sample) -> None:
        try:
            Heartbeat.model_validate_json(sample.payload.to_bytes())  # only a well-formed heartbeat counts
        except ValidationError:
            return
        with self._lock:
            self._last_heartbeat = time.monotonic()
            lost = bool(self._lost)
        if lost:
            self._controller_back("heartbeat")

    def _controller_back(self, how: str) -> None:
        """A controller is heard from while jobs aborted for its loss are unconfirmed: send their stops again."""
        with self._lock:
            lost, self._lost = self._lost, {}
        for job_id, info in lost.items():
            reason = f"stop re-sent: the controller lost during job {job_id} is back ({how})"
            sent_at = self._send_stop(job_id, reason)
            data = {"job_id": job_id, "reason": reason, "sent_at": sent_at, "aborted_for": info.get("reason"),
                    "lost_for_s": time.monotonic() - info["at"]}
            callback = self.on_controller_return
            if callback is not None:
                try:
                    callback(job_id, data)
                except Exception:  # noqa: BLE001 - a failing recorder must not stop the re-send of others
                    pass

    def _on_joints(self, sample: zenoh.Sample) -> None:
        try:
            js = JointState.model_validate_json(sample.payload.to_bytes())
        except ValidationError:
            return
        with self._lock:
            self._joint_state, self._joint_state_at = js, time.monotonic()

    def _on_exec(self, sample: zenoh.Sample) -> None:
        try:
            self._exec.put((time.monotonic(), ExecStatus.model_validate_json(sample.payload.to_bytes())))
        except ValidationError:
            pass

    # ------------------------------------------------------------------ status
    def zid(self) -> str:
        """This peer's zenoh id (for diagnostics and tests)."""
        return str(self._session.info.zid()) if self._session is not None else ""

    def controller_problem(self, since: float | None = None) -> str | None:
        """Why the controller is not usable now, or None when it is alive (token and fresh heartbeat).

        ``since``: judge the heartbeat's age from no earlier than this (``time.monotonic()``): the moment this
        process could run again after it was itself held up, when the heartbeats that came meanwhile were
        still waiting for its interpreter."""
        with self._lock:
            token, beat = self._token_alive, self._last_heartbeat
        if not token:
            return f"no controller: liveliness token {self.keys.alive} is absent"
        if beat is None:
            return "no controller heartbeat received yet"
        age = time.monotonic() - (beat if since is None else max(beat, since))
        if age > self.settings.watchdog_timeout_s:
            return f"controller heartbeat lost: none for {age * 1000:.0f} ms (watchdog {self.settings.watchdog_timeout_s * 1000:.0f} ms)"
        return None

    def last_heartbeat_at(self) -> float | None:
        """``time.monotonic()`` of the last heartbeat received, or None."""
        with self._lock:
            return self._last_heartbeat

    def controller_alive(self) -> bool:
        return self.controller_problem() is None

    def wait_for_controller(self, timeout_s: float) -> bool:
        """Wait (bounded) until a controller is alive and its joint state is known."""
        return wait_for_controller(self, timeout_s)

    def measured_state(self) -> JointState | None:
        """The latest joint state, or None when none arrived within ``state_max_age_s``."""
        with self._lock:
            js, at = self._joint_state, self._joint_state_at
        if js is None or at is None or time.monotonic() - at > self.dispatch.state_max_age_s:
            return None
        return js

    # ------------------------------------------------------------------ commands
    def stop(self, job_id: str | None = None, reason: str = "stop requested by operator") -> float:
        """Publish ``cmd/stop`` now (repeated a few times); a running execution of that job ends aborted.

        Returns the ``time.monotonic()`` at which the first stop was published."""
        with self._lock:
            self._stop_requests.add(job_id)
        return self._send_stop(job_id, reason)

    def _stop_bytes(self, job_id: str | None, reason: str) -> bytes:
        """A stop, signed when a key is there (a controller obeys it unsigned too)."""
        now = time.monotonic()
        msg = Stop(job_id=job_id, reason=reason, stamp=now, expires_at=time.time() + self.settings.segment_expiry_s)
        doc = msg.model_dump(mode="json", exclude={"sig"})
        if self.signer is None:
            return canonical_bytes(doc)
        return self.signer.encode(doc)

    def _send_stop(self, job_id: str | None, reason: str, repeats: int | None = None) -> float:
        n = repeats if repeats is not None else self.settings.stop_repeats
        sent_at = time.monotonic()
        self._pub_stop.put(self._stop_bytes(job_id, reason))
        if n > 1:
            def again() -> None:
                for _ in range(n - 1):
                    time.sleep(self.settings.stop_repeat_period_s)
                    try:
                        self._pub_stop.put(self._stop_bytes(job_id, reason))
                    except Exception:
                        return
            threading.Thread(target=again, name="stop-repeat", daemon=True).start()
        return sent_at

    def _next_seq(self, count: int) -> int:
        with self._lock:
            first = self._seq
            self._seq += count
        return first

    # ------------------------------------------------------------------ execution
    def execute(self, plan: dict[str, Any] | str | bytes, *, job_id: str, approved_sha256: str, approval_expires_at: datetime,
                threshold_m: float | None = None, on_event: EventCallback | None = None,
                stop_event: threading.Event | None = None, recovery: bool = False) -> ExecutionResult:
        """Gate the plan, send it, follow it to the end.

        ``plan`` is the plan dict, or its canonical JSON text or bytes (``schemas.plan.canonical_json``):
        the bytes are hashed as they are, which saves about a second on a 60 s plan.

        Raises :class:`NoSigningKeyError` without a signing key, :class:`ControllerUnavailableError`
        before anything happens when no controller is alive or its state is unknown (the job stays
        approved), and :class:`BusyError` when another execution runs. ``recovery``: the plan is a
        recover job's (the gate's margin floor is then its start where that is under the threshold).
        """
        if self.signer is None:
            raise NoSigningKeyError("the bridge has no signing key (REGRASP_BRIDGE_SIGNING_KEY): a controller refuses "
                                    "unsigned commands, so nothing is dispatched; make a pair with "
                                    "'regrasp keys generate DIR'")
        if not self._run_lock.acquire(blocking=False):
            raise BusyError("another execution is running on this dispatcher")
        try:
            return self._execute(plan, job_id, approved_sha256, approval_expires_at, threshold_m, on_event or (lambda k, d: None),
                                 stop_event or threading.Event(), recovery)
        finally:
            self._run_lock.release()

    def _execute(self, plan: dict[str, Any] | str | bytes, job_id: str, approved_sha256: str, expires_at: datetime,
                 threshold_m: float | None, emit: EventCallback, stop_event: threading.Event,
                 recovery: bool = False) -> ExecutionResult:
        started = time.monotonic()
        with self._lock:
            token = self._token_alive
        if token:
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
                                                   recovery=recovery)
            plan = parsed if parsed is not None else {}  # None only with a veto (the plan is not read on)
        else:
            verdict = self.gate.check(plan, approval=approval, measured=measured, threshold_m=threshold_m,
                                      recovery=recovery)
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
        self._drain_exec()
        # Serialised once, now: a send (and a re-send) then only splices in its expires_at and signs.
        self._payloads = {seg.seq: SignedSegment(seg) for seg in segments}
        run = _Run(job_id=job_id, segments=segments, seqs=frozenset(seg.seq for seg in segments))
        with self._lock:
            self._lost.pop(job_id, None)
        try:
            return self._follow(run, emit, stop_event, verdict, started)
        except Exception as exc:  # fail safe: whatever broke, the robot is told to stop
            self._end_heartbeat()
            self._send_stop(job_id, f"bridge error: {exc}")
            emit("stop_sent", {"job_id": job_id, "reason": f"bridge error: {exc}"})
            return ExecutionResult("aborted", f"bridge error: {type(exc).__name__}: {exc}", verdict, run.index, run.sent,
                                   time.monotonic() - started)
        finally:
            self._end_heartbeat()
            self._payloads = {}  # a finished execution's bytes are not kept until the next one

    def _drain_exec(self) -> None:
        while True:
            try:
                self._exec.get_nowait()
            except queue.Empty:
                return

    def _send_segment(self, run: "_Run", emit: EventCallback) -> None:
        seg = run.segments[run.sent]
        sent_at = time.monotonic()
        self._publish_segment(seg)
        if run.sent == 0:
            self._begin_heartbeat(run.job_id)  # the controller arms its dead-man at this segment
        run.pending[seg.seq] = (sent_at, 0)
        run.last_new_at = sent_at
        run.sent += 1
        emit("segment", {"job_id": run.job_id, "seq": seg.seq, "segment_index": seg.segment_index,
                         "segment_count": seg.segment_count, "first_index": seg.first_index, "points": len(seg.points),
                         "t_from_start": seg.t_from_start, "sent_at": sent_at})

    def _resend(self, run: "_Run", emit: EventCallback, now: float, due: Callable[[float], bool], cause: str) -> None:
        """Send again the unacknowledged segments whose last send is ``due`` (same seq: the controller drops
        duplicates). The controller refuses whatever comes after a gap, so the segments behind the oldest
        unacknowledged one go again with it, but only that one spends its re-send budget: they were refused
        for its loss, and a budget spent on that would be gone when they become the gap."""
        d = self.dispatch
        waiting = sorted(run.pending.items())
        head = waiting[0][0] if waiting else None
        for seq, (sent_at, count) in waiting:
            if due(sent_at) and (count < d.max_resends or seq != head):
                self._publish_segment(run.segments[seq - run.segments[0].seq])
                spent = count + 1 if seq == head else count
                run.pending[seq] = (now, spent)
                emit("segment", {"job_id": run.job_id, "seq": seq, "resent": spent, "behind_gap": seq != head,
                                 "cause": cause})

    def _publish_segment(self, seg: TrajectorySegment) -> None:
        """Put one segment of the running execution on ``cmd/trajectory`` (the only place that does), as serialised
        when the gate passed the plan, with its receipt deadline and signature of now."""
        assert self.signer is not None
        self._pub_traj.put(self._payloads[seg.seq].wire(self.signer, time.time() + self.settings.segment_expiry_s))

    # ------------------------------------------------------------------ the dispatcher's heartbeat (dead-man)
    def _begin_heartbeat(self, job_id: str) -> None:
        with self._lock:
            self._heartbeat_job = job_id
        self._heartbeat_wake.set()

    def _end_heartbeat(self) -> None:
        with self._lock:
            self._heartbeat_job = None

    def _heartbeat_loop(self) -> None:
        """Publish ``cmd/heartbeat`` every period while an execution runs: a small signed message and nothing
        else on this thread (no events, no locks held across a send), at the bridge's thread priority."""
        raise_thread_priority(self.settings.thread_nice)
        period = self.settings.heartbeat_period_s
        job, seq = None, 0
        next_at = time.monotonic()
        while not self._closing.is_set():
            with self._lock:
                current = self._heartbeat_job
            if current is None:
                job = None
                self._heartbeat_wake.wait(0.5)
                self._heartbeat_wake.clear()
                next_at = time.monotonic()
                continue
            if current != job:
                job, seq = current, 0
            now_unix = time.time()
            msg = {"job_id": job, "seq": seq, "t": now_unix, "expires_at": now_unix + self.settings.heartbeat_expiry_s}
            try:
                self._pub_heartbeat.put(self.signer.encode(msg) if self.signer is not None else canonical_bytes(msg))
            except Exception:  # noqa: BLE001 - a closed session ends the loop below
                if self._closing.is_set():
                    return
            seq += 1
            next_at += period
            delay = next_at - time.monotonic()
            if delay <= 0:
                next_at = time.monotonic()  # late: the next one goes now, no burst to catch up
                continue
            self._heartbeat_wake.wait(delay)
            self._heartbeat_wake.clear()

    def _abort(self, run: "_Run", emit: EventCallback, reason: str, verdict: GateVerdict, started: float,
               wait_ack: bool = False, lost: bool = False) -> ExecutionResult:
        # The heartbeat ends first: should the stop not arrive, the controller's dead-man stops the robot.
        self._end_heartbeat()
        if lost:
            with self._lock:
                self._lost[run.job_id] = {"reason": reason, "at": time.monotonic()}
        self._send_stop(run.job_id, reason)
        emit("stop_sent", {"job_id": run.job_id, "reason": reason})
        acked = False
        if wait_ack:
            deadline = time.monotonic() + self.dispatch.ack_timeout_s
            while time.monotonic() < deadline and not acked:
                try:
                    _, st = self._exec.get(timeout=self.dispatch.poll_period_s)
                except queue.Empty:
                    continue
                acked = st.status == "stopped"
                if st.index is not None:
                    run.index = st.index
        result = ExecutionResult("aborted", reason, verdict, run.index, run.sent, time.monotonic() - started,
                                 {"stop_acknowledged": acked} if wait_ack else {})
        emit("finished", result.to_dict())
        return result

    def _follow(self, run: "_Run", emit: EventCallback, stop_event: threading.Event, verdict: GateVerdict,
                started: float) -> ExecutionResult:
        d = self.dispatch
        ahead = d.lookahead_segments

        def window_open(now: float) -> bool:
            """Fewer than the window unacknowledged; or the oldest of them waited too long for its acknowledgement
            and no segment went out for as long (late acknowledgements let one more out per ``in_flight_wait_s``)."""
            if len(run.pending) < d.max_in_flight_segments:
                return True
            return (now - min(sent_at for sent_at, _ in run.pending.values()) > d.in_flight_wait_s
                    and now - run.last_new_at > d.in_flight_wait_s)

        # The watchdog judges only time this loop could run: after the gate (a long check holds the interpreter)
        # or any stall of this process, the heartbeats already here get their callbacks before one is missed.
        resumed_at = last_iteration = time.monotonic()
        while run.sent < min(len(run.segments), ahead) and window_open(time.monotonic()):
            self._send_segment(run, emit)
        last_progress = time.monotonic()
        last_state_event = 0.0
        executing_announced = False
        per = len(run.segments[0].points)
        while True:
            with self._lock:
                stop_requested = run.job_id in self._stop_requests or None in self._stop_requests
            if stop_event.is_set() or stop_requested:
                return self._abort(run, emit, "stopped by operator", verdict, started, wait_ack=True)
            tick = time.monotonic()
            if tick - last_iteration > d.self_stall_s:
                resumed_at = tick
            last_iteration = tick
            problem = self.controller_problem(since=resumed_at)
            if problem is not None:
                return self._abort(run, emit, f"controller lost: {problem}", verdict, started, lost=True)
            try:
                at, st = self._exec.get(timeout=d.poll_period_s)
            except queue.Empty:
                st = None
            now = time.monotonic()
            if st is not None and st.job_id == run.job_id:
                if st.index is not None:
                    run.index = st.index
                if st.status in ("accepted", "duplicate") and st.seq is not None:
                    run.pending.pop(st.seq, None)
                if st.status in ("accepted", "executing", "duplicate"):
                    last_progress = now
                    if not executing_announced and st.status in ("accepted", "executing"):
                        executing_announced = True
                        emit("executing", {"job_id": run.job_id, "index": run.index or 0, "status": st.status})
                    elif st.status == "executing":
                        emit("executing", {"job_id": run.job_id, "index": run.index, "status": "executing"})
                    if st.status == "accepted":
                        emit("segment", {"job_id": run.job_id, "seq": st.seq, "acknowledged": True, "received_at": st.received_at})
                    if st.status == "duplicate":
                        emit("controller", {"job_id": run.job_id, "status": st.status, "seq": st.seq, "reason": st.reason})
                elif st.status == "succeeded":
                    result = ExecutionResult("succeeded", st.reason or "trajectory executed", verdict, st.index, run.sent,
                                             now - started)
                    emit("finished", result.to_dict())
                    return result
                elif st.status in ("rejected", "refused") and not st.fatal:
                    emit("controller", {"job_id": run.job_id, "status": st.status, "seq": st.seq, "reason": st.reason,
                                        "fatal": False, "kind": st.kind})
                    # Refused for a gap before it (or it came too late): the gap and what follows go again now,
                    # in order. A refused copy that is not ours (a forged one) changes nothing on the controller.
                    if st.kind != "heartbeat" and st.seq in run.pending and now - run.gap_resent_at > d.gap_holdoff_s:
                        run.gap_resent_at = now
                        self._resend(run, emit, now, due=lambda sent_at: True, cause="gap")
                elif st.status == "refused" and (st.kind == "heartbeat" or st.seq not in run.seqs):
                    # Fatal for a message that is not one of this execution's segments: a heartbeat racing the end
                    # of the job, or someone else's command. Recorded; the controller's own end comes as 'stopped'.
                    emit("controller", {"job_id": run.job_id, "status": st.status, "seq": st.seq, "reason": st.reason,
                                        "kind": st.kind})
                elif st.status in ("rejected", "refused", "starved", "fault", "stopped"):
                    emit("controller", {"job_id": run.job_id, "status": st.status, "seq": st.seq, "reason": st.reason})
                    return self._abort(run, emit, f"controller {st.status}: {st.reason}", verdict, started)
            elif st is not None and st.status == "refused" and st.job_id is None:
                # An unreadable command refused: not this execution's (its segments name their job).
                emit("controller", {"job_id": run.job_id, "status": st.status, "reason": st.reason, "kind": st.kind})
            elif st is not None and st.status == "rejected" and st.job_id is None:
                emit("controller", {"job_id": run.job_id, "status": st.status, "reason": st.reason})
                return self._abort(run, emit, f"controller rejected a command: {st.reason}", verdict, started)
            self._resend(run, emit, now, due=lambda sent_at: now - sent_at > d.resend_after_s, cause="timeout")
            # keep the controller fed: stay `lookahead` segments ahead of the one being played, at most
            # `max_in_flight_segments` of them unacknowledged unless an acknowledgement is late
            playing = (run.index or 0) // per
            while run.sent < len(run.segments) and run.sent <= playing + ahead and window_open(now):
                self._send_segment(run, emit)
            if now - last_progress > d.progress_timeout_s:
                return self._abort(run, emit, f"no progress from the controller for {d.progress_timeout_s:.1f} s", verdict, started)
            if now - last_state_event >= d.robot_state_event_period_s:
                js = self.measured_state()
                if js is not None:
                    emit("robot_state", {"stamp": js.stamp, "joint_names": js.joint_names, "q": js.q, "index": js.index})
                last_state_event = now

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        if self._session is None:
            return
        self._closing.set()
        self._heartbeat_wake.set()
        self._heartbeat_thread.join(timeout=1.0)
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        self._session.close()
        self._session = None

    def __enter__(self) -> "Dispatcher":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _thread_nice() -> int | None:
    """The calling thread's niceness (Linux: per thread), or None where it cannot be read."""
    import os

    try:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    except (AttributeError, OSError):
        return None


@dataclass
class _Run:
    job_id: str
    segments: list[TrajectorySegment]
    seqs: frozenset[int] = frozenset()
    sent: int = 0
    index: int | None = None
    pending: dict[int, tuple[float, int]] = field(default_factory=dict)  # seq -> (last sent, re-sends)
    last_new_at: float = -math.inf  # when a segment last went out for the first time
    gap_resent_at: float = -math.inf  # when a refusal for a gap last started a re-send


def wait_for_controller(bridge: Any, timeout_s: float) -> bool:
    """Wait (bounded) until ``bridge`` (a dispatcher or its process proxy) sees a live controller whose
    joint state is known."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if bridge.controller_alive() and bridge.measured_state() is not None:
            return True
        time.sleep(0.01)
    return False
