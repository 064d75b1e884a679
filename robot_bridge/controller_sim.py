"""A simulated HRP-5P controller peer that speaks the bridge protocol (docs/contract.md section 6).

It stands in its initial posture (given as data: the CLI computes the stance), and
at its control rate (200 Hz) it publishes joint states, a heartbeat and, while a
job runs, progress. Segments are buffered and played by linear interpolation at
``dt_s`` from the start of segment 0, ``speed`` times faster than real time when
asked. Playback starts once a start buffer of motion is held (a jitter buffer: a
bridge paused for a moment by its host must not starve a controller that has only
just begun), or the whole job, or when the buffer has waited its own length.
Like a real controller it trusts nothing: it rejects out-of-order segments,
drops stale or duplicated ones (by ``seq``), checks joint limits and continuity
itself, holds the last command when the next point does not arrive in time, and
honours every stop at once.

Fault injection for tests and demos: drop a share of incoming commands, delay
them, crash (hard exit) after N accepted segments, freeze the heartbeat while
staying alive.

This module must not import the planner: the initial posture and limits come in
as arrays.
"""

from __future__ import annotations

import math
import os
import queue
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from schemas.bridge import ExecStatus, Heartbeat, JointState, Stop, TrajectorySegment

from .process_tuning import freeze_startup_objects
from .settings import BridgeSettings, Keys
from .zenoh_session import control_publisher, encode, open_session, telemetry_publisher

#: Exit code of an injected crash.
CRASH_EXIT_CODE = 3


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
        self.count = 0
        self.state = "executing"  # executing | succeeded | stopped | starved | fault | rejected
        self.tau = 0.0  # plan time played so far (s)
        self.index = 0

    def point(self, i: int) -> np.ndarray:
        for block in self.points:
            if i < len(block):
                return block[i]
            i -= len(block)
        raise IndexError(i)

    @property
    def complete(self) -> bool:
        return self.last_index == self.segment_count - 1


class ControllerSim:
    """The simulated controller; ``start()`` then ``wait()``; ``close()`` ends it cleanly."""

    def __init__(self, bridge: BridgeSettings, sim: ControllerSimSettings, joint_names: list[str], q0: np.ndarray,
                 limits: JointLimits, *, exit_fn: Callable[[int], None] = os._exit):
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
        ]
        self._token = s.liveliness().declare_token(self.keys.alive)
        for target, name in ((self._control_loop, "control"), (self._command_loop, "commands")):
            t = threading.Thread(target=target, name=f"controller-sim-{name}", daemon=True)
            t.start()
            self._threads.append(t)

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
                self._status(None, None, "rejected", f"internal error handling a command: {exc}", received)

    def _handle_stop(self, payload: bytes, received: float) -> None:
        try:
            stop = Stop.model_validate_json(payload)
        except ValidationError as exc:
            stop = Stop(reason=f"malformed stop treated as stop-all: {exc.error_count()} errors")
        with self._lock:
            job = self._job
            # Every stop is honoured, whichever job it names: the robot holds its posture.
            if job is not None and job.state == "executing":
                job.state = "stopped"
            job_id = job.job_id if job is not None else stop.job_id
            seq = job.last_seq if job is not None else None
            index = job.index if job is not None else None
        self._status(job_id, seq, "stopped", stop.reason or "stop requested", received, index)

    def _handle_segment(self, payload: bytes, received: float) -> None:
        try:
            seg = TrajectorySegment.model_validate_json(payload)
        except ValidationError as exc:
            self._status(None, None, "rejected", f"malformed segment: {exc.errors()[0]['msg']}", received)
            return
        reply: tuple[str, str] | None = None
        fatal = True
        crash = False
        with self._lock:
            job = self._job
            if job is not None and job.job_id == seg.job_id:
                if seg.seq <= job.last_seq:
                    reply = ("ignored", f"stale or duplicated seq {seg.seq} (last {job.last_seq})")
                elif job.state != "executing":
                    reply = ("rejected", f"job {job.job_id} already ended ({job.state})")
                elif seg.seq != job.last_seq + 1 or seg.segment_index != job.last_index + 1:
                    # Ahead of a gap: refuse it (never play out of order) but keep the job; the
                    # bridge re-sends what is missing, and starvation ends the job if it never comes.
                    reply = ("rejected", f"out of order: expected seq {job.last_seq + 1} / segment {job.last_index + 1}, "
                             f"got seq {seg.seq} / segment {seg.segment_index}")
                    fatal = False
                else:
                    reply = self._accept(job, seg)
            elif job is not None and job.state == "executing":
                reply = ("rejected", f"busy with job {job.job_id}")
            elif seg.segment_index != 0:
                reply = ("rejected", f"out of order: job {seg.job_id} must start with segment 0, got {seg.segment_index}")
                fatal = False  # segment 0 may still come (it is sent again)
            else:
                columns, problem = self._columns(seg)
                if problem:
                    reply = ("rejected", problem)
                else:
                    new = _Job(seg, columns)
                    reply = self._accept(new, seg)
                    if reply[0] == "accepted":
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
                    events = self._advance(job, period * self.sim.speed, now)
                q = self.q.copy()
                job_id = job.job_id if job is not None else None
                index = job.index if job is not None else None
                executing = job is not None and job.state == "executing"
                holding = job is not None and job.state in ("stopped", "starved", "fault", "rejected")
                seq = job.last_seq if job is not None else None
            for status, reason in events:
                self._status(job_id, seq, status, reason, None, index)
            self._pub_joints.put(encode(JointState(stamp=now, joint_names=self.joint_names, q=q.tolist(),
                                                   job_id=job_id if executing else None, index=index if executing else None)))
            if executing and now >= next_progress:
                self._status(job_id, seq, "executing", "", None, index)
                next_progress = now + self.sim.progress_period_s
            if now >= next_heartbeat and not self._heartbeat_frozen(now):
                state = "executing" if executing else ("holding" if holding else "idle")
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
            job.tau, job.index, job.state = (total_known - 1) * job.dt, total_known - 1, "succeeded"
            return [("succeeded", f"{total_known} points played")]
        if i + 1 >= total_known:
            job.state = "starved"  # the next point is not here: hold the last command
            return [("starved", f"point {i + 1} missing (segment {job.last_index + 1} not received); holding posture")]
        a, b = job.point(i), job.point(i + 1)
        q = a + (f - i) * (b - a)
        lim = self.limits
        if np.any(q < lim.lower - self.sim.position_tolerance) or np.any(q > lim.upper + self.sim.position_tolerance):
            job.state = "fault"
            return [("fault", "joint limit reached during playback; holding posture")]
        self.q = q
        job.tau, job.index = tau, i
        return []

    def _status(self, job_id: str | None, seq: int | None, status: str, reason: str, received: float | None,
                index: int | None = None, fatal: bool = True) -> None:
        if self._session is None:
            return
        self._pub_exec.put(encode(ExecStatus(job_id=job_id, seq=seq, index=index, status=status, reason=reason,
                                             received_at=received, fatal=fatal)))


def run_controller(bridge: BridgeSettings, sim: ControllerSimSettings, joint_names: list[str], q0: np.ndarray,
                   limits: JointLimits, on_ready: Callable[[ControllerSim], None] | None = None,
                   stop: threading.Event | None = None) -> None:
    """Run a controller until ``stop`` is set (or forever); the CLI's entry point."""
    sys.setswitchinterval(sim.switch_interval_s)
    ctl = ControllerSim(bridge, sim, joint_names, q0, limits)
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
