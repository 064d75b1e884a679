"""A simulated HRP-5P controller peer that speaks the bridge protocol (docs/contract.md section 6).

It stands in its initial posture (given as data: the CLI computes the stance), and
at its control rate (200 Hz) it publishes joint states, a heartbeat and, while a
job runs, progress. Segments are buffered and played by linear interpolation at
``dt_s`` from the start of segment 0, ``speed`` times faster than real time when
asked. Playback starts once a start buffer of motion is held (a jitter buffer: a
bridge paused for a moment by its host must not starve a controller that has only
just begun), or the whole job, or when the buffer has waited its own length.
Like a real controller it trusts nothing (docs/robot_bridge.md has the checklist
a real controller's adapter implements, this simulator being its reference):

- every ``cmd/*`` message must carry a good Ed25519 signature by the trusted key
  and arrive before its ``expires_at`` (plus the allowed clock skew); otherwise it
  is ``refused`` with the reason and the job id and sequence read from the raw
  message, and nothing moves. ``cmd/stop`` alone is obeyed unsigned (and logged);
- a segment of a job it ended, of another job while one runs, or out of sequence
  is refused; a re-sent copy of a segment it holds is a ``duplicate``;
- the dead-man: from the first accepted segment of a job, the dispatcher's
  heartbeat (``cmd/heartbeat``) must arrive at least every watchdog period, timed
  on this process's monotonic clock at receipt. When it does not (the dispatcher
  died, the link broke, or this controller was frozen), the controller stops by
  itself, drops every buffered segment, reports ``stopped`` and never plays that
  job again, however long it was frozen;
- it checks joint limits and continuity itself, holds the last command when the
  next point does not arrive in time, and honours every stop at once.

Fault injection for tests and demos: drop a share of incoming commands, delay
them, crash (hard exit) after N accepted segments, freeze the heartbeat while
staying alive.

This module must not import the planner: the initial posture and limits come in
as arrays.
"""

from __future__ import annotations

import json
import math
import os
import queue
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from schemas.bridge import (
    CommandHeartbeat,
    ExecStatus,
    Heartbeat,
    JointState,
    Stop,
    TrajectorySegment,
)

from .process_tuning import (
    freeze_startup_objects,
    raise_thread_priority,
    use_realtime_scheduling,
)
from .settings import BridgeSettings, Keys
from .signing import Verifier, open_signed
from .zenoh_session import control_publisher, encode, open_session, telemetry_publisher

#: Exit code of an injected crash.
CRASH_EXIT_CODE = 3
#: The shortest pause between control ticks, s (when a tick overran its period).
MIN_TICK_PAUSE_S = 0.0005
#: Jobs remembered as ended (their segments refused), most recent first out when full.
ENDED_JOBS_KEPT = 10_000


class ControllerSimSettings(BaseModel):
    """Playback and fault injection of the simulated controller."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    speed: float = Field(1.0, gt=0, le=1000, description="play trajectories this many times faster than real time")
    rate_hz: float = Field(200.0, gt=0, le=2000, description="control and joint-state rate")
    start_buffer_s: float = Field(
        0.5, ge=0, le=10.0,
        description="wall-clock time of motion held before playback starts (plan time / speed), unless the whole job "
                    "is held first or the first segment has waited this long: at 10x a 0.25 s segment lasts 25 ms, and "
                    "a bridge paused longer than that by its host (a VM's steal) starved a controller that began at once",
    )
    progress_period_s: float = Field(0.05, gt=0, description="period of 'executing' progress reports")
    start_tolerance_rad: float = Field(0.02, gt=0, description="segment 0's first point vs the current posture")
    limit_tolerance_rel: float = Field(1e-6, ge=0, description="slack on the velocity limits")
    position_tolerance: float = Field(1e-9, ge=0, description="slack on the position limits (rad or m)")
    drop_rate: float = Field(0.0, ge=0, le=1, description="share of incoming commands silently dropped")
    delay_ms: float = Field(0.0, ge=0, le=10_000, description="extra delay before a command is handled")
    crash_after: int | None = Field(None, ge=1, description="hard exit right after accepting this many segments")
    freeze_heartbeat_after_s: float | None = Field(
        None, ge=0, description="stop the heartbeat this long after the first accepted segment, staying alive otherwise"
    )
    seed: int = Field(0, description="seed of the drop decisions")
    controller_id: str = "controller-sim"
    stance: str = Field("upright", description="the stance the robot stands in, reported on state/joints")
    holding: Literal["none", "left", "right", "both"] = Field("none", description="what the hands hold at start")
    switch_interval_s: float = Field(
        0.0002, gt=0, le=0.005,
        description="Python's thread switch interval in the controller's process (run_controller sets it): a zenoh "
                    "callback waits at most about this long for the interpreter while the control or command thread "
                    "runs Python; at the default 5 ms, arriving commands waited up to 5 ms",
    )


@dataclass(frozen=True)
class JointLimits:
    """Position and velocity limits in the controller's own joint order."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray


class _Job:
    """What the controller knows about the job it plays (or last played)."""

    def __init__(self, seg: TrajectorySegment, columns: np.ndarray):
        self.created = time.monotonic()
        self.playing = False  # the start buffer is full (or waited long enough): playback runs
        self.job_id = seg.job_id
        self.plan_sha256 = seg.plan_sha256
        self.dt = seg.dt_s
        self.segment_count = seg.segment_count
        self.columns = columns  # segment joint order -> own order
        self.last_seq = -1
        self.last_index = -1
        self.points: list[np.ndarray] = []  # one (k, n) block per segment, own order
        self.holding: list[list[str]] = []  # the holding of each point, per block
        self.count = 0
        self.last_heartbeat: float | None = None  # receipt (monotonic) of the last dispatcher heartbeat; armed when set
        self.heartbeat_seq = -1
        self.state = "executing"  # executing | succeeded | stopped | starved | fault | rejected
        self.tau = 0.0  # plan time played so far (s)
        self.index = 0

    def point(self, i: int) -> np.ndarray:
        for block in self.points:
            if i < len(block):
                return block[i]
            i -= len(block)
        raise IndexError(i)

    def holding_at(self, i: int) -> str | None:
        for block in self.holding:
            if i < len(block):
                return block[i]
            i -= len(block)
        return None

    @property
    def complete(self) -> bool:
        return self.last_index == self.segment_count - 1


class ControllerSim:
    """The simulated controller; ``start()`` then ``wait()``; ``close()`` ends it cleanly."""

    def __init__(self, bridge: BridgeSettings, sim: ControllerSimSettings, joint_names: list[str], q0: np.ndarray,
                 limits: JointLimits, *, exit_fn: Callable[[int], None] = os._exit, verifier: Verifier | None = None,
                 log: Callable[[str], None] | None = None):
        if len(joint_names) != len(q0):
            raise ValueError(f"{len(joint_names)} joint names for {len(q0)} initial values")
        if not np.all(np.isfinite(q0)):
            raise ValueError("the initial posture is not finite")
        self.bridge, self.sim = bridge, sim
        self.keys = Keys(bridge.robot_id)
        self.joint_names = list(joint_names)
        self._col = {n: i for i, n in enumerate(joint_names)}
        self.q = np.array(q0, dtype=float)
        self.limits = limits
        self._exit = exit_fn
        self._lock = threading.Lock()
        self._inbox: queue.Queue = queue.Queue()
        self._closing = threading.Event()
        self._job: _Job | None = None
        self._ended: dict[str, str] = {}  # job id -> how it ended; their segments are refused
        self._verifier = verifier
        self._log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self._holding = sim.holding
        self._accepted = 0
        self._first_accept: float | None = None
        self._rng = np.random.default_rng(sim.seed)
        self._threads: list[threading.Thread] = []
        self._session: zenoh.Session | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        s = self._session = open_session(self.bridge)
        self._pub_joints = telemetry_publisher(s, self.keys.joints)
        self._pub_exec = control_publisher(s, self.keys.exec)
        self._pub_heartbeat = control_publisher(s, self.keys.heartbeat)
        self._subs = [
            s.declare_subscriber(self.keys.trajectory, self._on_command),
            s.declare_subscriber(self.keys.stop, self._on_command),
            # The dead-man's input is handled in zenoh's callback itself: a heartbeat never waits behind a segment.
            s.declare_subscriber(self.keys.command_heartbeat, self._on_heartbeat),
        ]
        self._token = s.liveliness().declare_token(self.keys.alive)
        for target, name in ((self._control_loop, "control"), (self._command_loop, "commands")):
            t = threading.Thread(target=self._prioritised(target), name=f"controller-sim-{name}", daemon=True)
            t.start()
            self._threads.append(t)

    def _prioritised(self, target: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            raise_thread_priority(self.bridge.thread_nice)
            target()
        return run

    def wait(self, timeout: float | None = None) -> bool:
        return self._closing.wait(timeout)

    def close(self) -> None:
        self._closing.set()
        self._inbox.put(None)
        for t in self._threads:
            t.join(timeout=1.0)
        if self._session is not None:
            try:
                self._token.undeclare()
            except Exception:
                pass
            self._session.close()
            self._session = None

    # ------------------------------------------------------------------ receiving
    def _on_command(self, sample: zenoh.Sample) -> None:
        """zenoh callback: hand over at once (never block zenoh's thread)."""
        self._inbox.put((time.monotonic(), str(sample.key_expr), sample.payload.to_bytes()))

    def _command_loop(self) -> None:
        delay = self.sim.delay_ms / 1000.0
        while not self._closing.is_set():
            item = self._inbox.get()
            if item is None:
                return
            received, key, payload = item
            if self.sim.drop_rate > 0 and self._rng.random() < self.sim.drop_rate:
                continue
            if delay > 0:
                wait = received + delay - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            try:
                if key == self.keys.stop:
                    self._handle_stop(payload, received)
                else:
                    self._handle_segment(payload, received)
            except Exception as exc:  # a bad message must never kill the controller
                self._status(None, None, "refused", f"internal error handling a command: {exc}", received)

    # ------------------------------------------------------------------ authentication
    def _open(self, payload: bytes, kind: str, received: float) -> dict | None:
        """The message as a dict if it is signed by the trusted key and not expired; else refused (None)."""
        if self._verifier is None:
            try:
                msg = json.loads(payload)
            except (ValueError, UnicodeDecodeError):
                msg = None
            problem = "no trusted key is configured: only cmd/stop is obeyed"
        else:
            msg, problem = open_signed(payload, self._verifier)
        if not isinstance(msg, dict):
            self._status(None, None, "refused", f"malformed {kind}: not a JSON object", received, kind=kind, fatal=False)
            return None
        if problem is None:
            problem = self._expiry_problem(msg)
        if problem is not None:
            job_id = msg.get("job_id") if isinstance(msg.get("job_id"), str) else None
            seq = msg.get("seq") if isinstance(msg.get("seq"), int) and not isinstance(msg.get("seq"), bool) else None
            # Not fatal: nothing changed for a running job (a forged or late copy is not the dispatcher's word).
            self._status(job_id, seq, "refused", f"{kind} refused: {problem}", received, kind=kind, fatal=False)
            return None
        return msg

    def _expiry_problem(self, msg: dict) -> str | None:
        expires = msg.get("expires_at")
        if not isinstance(expires, (int, float)) or isinstance(expires, bool) or not math.isfinite(expires):
            return "no expires_at"
        late = time.time() - (float(expires) + self.bridge.clock_skew_s)
        if late > 0:
            return (f"expired: received {late + self.bridge.clock_skew_s:.3f} s after its expires_at "
                    f"(clock skew allowance {self.bridge.clock_skew_s:.3f} s)")
        return None

    # ------------------------------------------------------------------ commands
    def _handle_stop(self, payload: bytes, received: float) -> None:
        """Obeyed whatever it carries (stopping is always safe); whether it was signed is logged."""
        try:
            raw = json.loads(payload)
        except (ValueError, UnicodeDecodeError):
            raw = None
        if self._verifier is None:
            auth = "unverified (no trusted key)"
        elif not isinstance(raw, dict):
            auth = "unsigned (malformed)"
        else:
            problem = self._verifier.problem(raw)
            auth = "signed" if problem is None else problem.split(":")[0]
        try:
            stop = Stop.model_validate(raw) if isinstance(raw, dict) else Stop.model_validate_json(payload)
        except ValidationError as exc:
            stop = Stop(reason=f"malformed stop treated as stop-all: {exc.error_count()} errors")
        with self._lock:
            job = self._job
            # Every stop is honoured, whichever job it names: the robot holds its posture.
            if job is not None and job.state == "executing":
                self._end(job, "stopped")
            job_id = job.job_id if job is not None else stop.job_id
            seq = job.last_seq if job is not None else None
            index = job.index if job is not None else None
        self._log(json.dumps({"event": "stop", "job_id": stop.job_id, "auth": auth, "reason": stop.reason}))
        self._status(job_id, seq, "stopped", f"{stop.reason or 'stop requested'} ({auth} stop)", received, index,
                     kind="stop")

    def _end(self, job: _Job, state: str) -> int:
        """End a job (lock held): nothing more of it is played; its buffered points are dropped. Returns how many."""
        job.state = state
        dropped = max(0, job.count - job.index - 1)
        job.points, job.holding = [], []
        self._ended[job.job_id] = state
        while len(self._ended) > ENDED_JOBS_KEPT:
            self._ended.pop(next(iter(self._ended)))
        return dropped

    def _on_heartbeat(self, sample: zenoh.Sample) -> None:
        """zenoh callback: the dispatcher's heartbeat, judged at receipt on this process's monotonic clock."""
        received = time.monotonic()
        msg = self._open(sample.payload.to_bytes(), "heartbeat", received)
        if msg is None:
            return
        try:
            hb = CommandHeartbeat.model_validate(msg)
        except ValidationError as exc:
            self._status(msg.get("job_id") if isinstance(msg.get("job_id"), str) else None, None, "refused",
                         f"malformed heartbeat: {exc.errors()[0]['msg']}", received, kind="heartbeat")
            return
        reply = None
        with self._lock:
            job = self._job
            if job is None or job.job_id != hb.job_id:
                if hb.job_id in self._ended:
                    reply = ("refused", f"heartbeat of job {hb.job_id}, which this controller ended "
                                        f"({self._ended[hb.job_id]})", None)
                # else: a heartbeat ahead of its job's first segment; the dead-man is not armed yet
            elif job.state != "executing":
                reply = ("refused", f"heartbeat of job {hb.job_id}, which this controller ended ({job.state})", None)
            elif hb.seq <= job.heartbeat_seq:
                reply = ("refused", f"heartbeat out of sequence: seq {hb.seq} after {job.heartbeat_seq}", None)
            elif job.last_heartbeat is not None and received - job.last_heartbeat > self.bridge.watchdog_timeout_s:
                # It came, but too late: the gap happened (this process may have been frozen through it).
                reply = self._dead_man(job, received)
            else:
                job.last_heartbeat, job.heartbeat_seq = received, hb.seq
        if reply is not None:
            status, reason, index = reply
            self._status(hb.job_id, hb.seq, status, reason, received, index, kind="heartbeat")

    def _dead_man(self, job: _Job, now: float) -> tuple[str, str, int]:
        """Stop the job: the dispatcher's heartbeat was missing past the watchdog (lock held)."""
        gap = now - (job.last_heartbeat or now)
        dropped = self._end(job, "stopped")
        reason = (f"dead-man: no dispatcher heartbeat for {gap * 1000:.0f} ms (watchdog "
                  f"{self.bridge.watchdog_timeout_s * 1000:.0f} ms); controlled stop, {dropped} buffered points dropped")
        return "stopped", reason, job.index

    def _handle_segment(self, payload: bytes, received: float) -> None:
        msg = self._open(payload, "segment", received)
        if msg is None:
            return
        try:
            seg = TrajectorySegment.model_validate(msg)
        except ValidationError as exc:
            job_id = msg.get("job_id") if isinstance(msg.get("job_id"), str) else None
            seq = msg.get("seq") if isinstance(msg.get("seq"), int) else None
            self._status(job_id, seq, "rejected", f"malformed segment: {exc.errors()[0]['msg']}", received)
            return
        reply: tuple[str, str] | None = None
        fatal = True
        crash = False
        with self._lock:
            job = self._job
            if seg.job_id in self._ended:  # every job that stops running is remembered here (_end)
                reply = ("refused", f"job {seg.job_id} was ended by this controller ({self._ended[seg.job_id]}); "
                                    "its segments are refused")
            elif job is not None and job.job_id == seg.job_id:
                if seg.seq <= job.last_seq:
                    reply = ("duplicate", f"seq {seg.seq} is already held (last {job.last_seq}); copy dropped")
                elif seg.seq != job.last_seq + 1 or seg.segment_index != job.last_index + 1:
                    # Ahead of a gap: refuse it (never play out of order) but keep the job; the bridge re-sends
                    # what is missing, and the dead-man or starvation ends the job if it never comes.
                    reply = ("refused", f"out of sequence: expected seq {job.last_seq + 1} / segment "
                                        f"{job.last_index + 1}, got seq {seg.seq} / segment {seg.segment_index}")
                    fatal = False
                else:
                    reply = self._accept(job, seg)
            elif job is not None and job.state == "executing":
                reply = ("refused", f"another job is running: {job.job_id}")
            elif seg.segment_index != 0:
                reply = ("refused", f"out of sequence: job {seg.job_id} must start with segment 0, got "
                                    f"{seg.segment_index}")
                fatal = False  # segment 0 may still come (it is sent again)
            else:
                columns, problem = self._columns(seg)
                if problem:
                    reply = ("rejected", problem)
                else:
                    new = _Job(seg, columns)
                    reply = self._accept(new, seg)
                    if reply[0] == "accepted":
                        new.last_heartbeat = received  # the dead-man arms at the first accepted segment
                        self._job = new
            if reply[0] == "accepted":
                self._accepted += 1
                if self._first_accept is None:
                    self._first_accept = time.monotonic()
                crash = self.sim.crash_after is not None and self._accepted >= self.sim.crash_after
        self._status(seg.job_id, seg.seq, reply[0], reply[1], received, fatal=fatal)
        if crash:
            self._exit(CRASH_EXIT_CODE)

    def _columns(self, seg: TrajectorySegment) -> tuple[np.ndarray, str]:
        unknown = [n for n in seg.joint_names if n not in self._col]
        missing = [n for n in self.joint_names if n not in seg.joint_names]
        if unknown or missing:
            return np.empty(0, int), f"joint names differ from the controller's: unknown {unknown}, missing {missing}"
        return np.array([self._col[n] for n in seg.joint_names]), ""

    def _accept(self, job: _Job, seg: TrajectorySegment) -> tuple[str, str]:
        """The controller's own checks on a segment (called with the lock held)."""
        if seg.plan_sha256 != job.plan_sha256 or abs(seg.dt_s - job.dt) > 1e-12 or seg.segment_count != job.segment_count:
            return "rejected", "plan_sha256, dt_s or segment_count changed within a job"
        first = int(round(seg.t_from_start / seg.dt_s))
        if first != job.count:
            return "rejected", f"t_from_start {seg.t_from_start} does not continue the buffered {job.count} points"
        pts = np.empty((len(seg.points), len(self.joint_names)))
        pts[:, job.columns] = np.array(seg.points, dtype=float)
        lim, tol = self.limits, self.sim.position_tolerance
        bad = np.argwhere((pts < lim.lower - tol) | (pts > lim.upper + tol))
        if bad.size:
            i, j = bad[0]
            return "rejected", f"joint limit: {self.joint_names[j]} = {pts[i, j]:.4f} outside [{lim.lower[j]:.4f}, {lim.upper[j]:.4f}]"
        prev = self.q if job.count == 0 else job.point(job.count - 1)
        if job.count == 0:
            dev = np.abs(pts[0] - prev)
            j = int(np.argmax(dev))
            if dev[j] > self.sim.start_tolerance_rad:
                return "rejected", f"start mismatch: {self.joint_names[j]} is {dev[j]:.4f} from the current posture"
        steps = np.abs(np.diff(np.vstack([prev[None], pts]), axis=0)) / seg.dt_s
        if job.count == 0:
            steps = steps[1:]
        over = np.argwhere(steps > lim.velocity * (1.0 + self.sim.limit_tolerance_rel) + 1e-12)
        if over.size:
            i, j = over[0]
            return "rejected", f"velocity limit: {self.joint_names[j]} at {steps[i, j]:.3f}, limit {lim.velocity[j]:.3f}"
        job.points.append(pts)
        job.holding.append(list(seg.holding))
        job.count += len(pts)
        job.last_seq, job.last_index = seg.seq, seg.segment_index
        return "accepted", f"{len(pts)} points buffered ({job.count} in all)"

    # ------------------------------------------------------------------ control loop
    def _control_loop(self) -> None:
        period = 1.0 / self.sim.rate_hz
        next_tick = time.monotonic()
        next_heartbeat = next_tick
        next_progress = next_tick
        beats = 0
        while not self._closing.is_set():
            now = time.monotonic()
            events = []
            with self._lock:
                job = self._job
                if job is not None and job.state == "executing":
                    # The dead-man first: after a freeze, nothing is played before the gap is judged.
                    if job.last_heartbeat is not None and now - job.last_heartbeat > self.bridge.watchdog_timeout_s:
                        status, reason, _ = self._dead_man(job, now)
                        events = [(status, reason)]
                    else:
                        events = self._advance(job, period * self.sim.speed, now)
                q = self.q.copy()
                holding = self._holding
                job_id = job.job_id if job is not None else None
                index = job.index if job is not None else None
                executing = job is not None and job.state == "executing"
                stopped = job is not None and job.state in ("stopped", "starved", "fault", "rejected")
                seq = job.last_seq if job is not None else None
            for status, reason in events:
                self._status(job_id, seq, status, reason, None, index)
            self._pub_joints.put(encode(JointState(stamp=now, joint_names=self.joint_names, q=q.tolist(),
                                                   job_id=job_id if executing else None, index=index if executing else None,
                                                   stance=self.sim.stance, holding=holding)))
            if executing and now >= next_progress:
                self._status(job_id, seq, "executing", "", None, index)
                next_progress = now + self.sim.progress_period_s
            if now >= next_heartbeat and not self._heartbeat_frozen(now):
                state = "executing" if executing else ("holding" if stopped else "idle")
                self._pub_heartbeat.put(encode(Heartbeat(controller_id=self.sim.controller_id, count=beats, stamp=now,
                                                         state=state, job_id=job_id)))
                beats += 1
                next_heartbeat = now + self.bridge.heartbeat_period_s
            next_tick += period
            sleep = next_tick - time.monotonic()
            if sleep > 0:
                time.sleep(sleep)
            else:
                next_tick = time.monotonic()  # fell behind: do not try to catch up in a burst
                # Never a tick without a pause: at real-time priority a loop that fell behind must not hold the core.
                time.sleep(MIN_TICK_PAUSE_S)

    def _heartbeat_frozen(self, now: float) -> bool:
        after = self.sim.freeze_heartbeat_after_s
        return after is not None and self._first_accept is not None and now - self._first_accept >= after

    def _advance(self, job: _Job, step: float, now: float) -> list[tuple[str, str]]:
        """Move the playback by ``step`` plan seconds once the start buffer is full; hold the last command when
        points are missing."""
        total_known = job.count
        if not job.playing:
            held_s = (total_known - 1) * job.dt / self.sim.speed
            job.playing = job.complete or held_s >= self.sim.start_buffer_s or now - job.created >= self.sim.start_buffer_s
            if not job.playing:
                return []
        tau = job.tau + step
        f = tau / job.dt
        i = int(math.floor(f))
        if job.complete and i >= total_known - 1:
            self.q = job.point(total_known - 1).copy()
            self._holding = job.holding_at(total_known - 1) or self._holding
            job.tau, job.index = (total_known - 1) * job.dt, total_known - 1
            self._end(job, "succeeded")
            return [("succeeded", f"{total_known} points played")]
        if i + 1 >= total_known:
            self._end(job, "starved")  # the next point is not here: hold the last command
            return [("starved", f"point {i + 1} missing (segment {job.last_index + 1} not received); holding posture")]
        a, b = job.point(i), job.point(i + 1)
        q = a + (f - i) * (b - a)
        lim = self.limits
        if np.any(q < lim.lower - self.sim.position_tolerance) or np.any(q > lim.upper + self.sim.position_tolerance):
            self._end(job, "fault")
            return [("fault", "joint limit reached during playback; holding posture")]
        self.q = q
        self._holding = job.holding_at(i) or self._holding
        job.tau, job.index = tau, i
        return []

    def _status(self, job_id: str | None, seq: int | None, status: str, reason: str, received: float | None,
                index: int | None = None, fatal: bool = True, kind: str | None = "trajectory") -> None:
        if status == "refused":
            self._log(json.dumps({"event": "refused", "kind": kind, "job_id": job_id, "seq": seq, "reason": reason}))
        if self._session is None:
            return
        self._pub_exec.put(encode(ExecStatus(job_id=job_id, seq=seq, index=index, status=status, reason=reason,
                                             received_at=received, fatal=fatal, kind=kind)))


def run_controller(bridge: BridgeSettings, sim: ControllerSimSettings, joint_names: list[str], q0: np.ndarray,
                   limits: JointLimits, on_ready: Callable[[ControllerSim], None] | None = None,
                   stop: threading.Event | None = None) -> None:
    """Run a controller until ``stop`` is set (or forever); the CLI's entry point.

    Without ``bridge.trusted_key`` the controller obeys only cmd/stop (every other command is refused)."""
    sys.setswitchinterval(sim.switch_interval_s)
    # Raised before zenoh opens: its runtime threads inherit this thread's priority.
    raise_thread_priority(bridge.thread_nice)
    use_realtime_scheduling(bridge.realtime_priority)
    verifier = Verifier.from_file(bridge.trusted_key) if bridge.trusted_key is not None else None
    ctl = ControllerSim(bridge, sim, joint_names, q0, limits, verifier=verifier)
    ctl.start()
    freeze_startup_objects()
    try:
        if on_ready is not None:
            on_ready(ctl)
        while not (stop.wait(0.2) if stop is not None else ctl.wait(0.2)):
            pass
    finally:
        ctl.close()


def limits_from_urdf(path: str, joint_names: list[str]) -> JointLimits:
    """Position and velocity limits from the URDF, in ``joint_names`` order (the gate's parser, not the planner)."""
    from .urdf_kinematics import load_urdf

    model = load_urdf(path)
    order = {n: i for i, n in enumerate(model.joint_names)}
    missing = [n for n in joint_names if n not in order]
    if missing:
        raise ValueError(f"joints {missing} are not movable joints of {path}")
    idx = np.array([order[n] for n in joint_names])
    return JointLimits(lower=model.lower[idx], upper=model.upper[idx], velocity=model.velocity_limit[idx])
