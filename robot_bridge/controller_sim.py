"""A simulated controller peer that speaks the bridge protocol (docs/contract.md section 6).

The protocol-and-safety layer, one piece whatever the plant: it stands in its initial posture (given as data: the
CLI computes the stance) and at its control rate (200 Hz) publishes joint states, a heartbeat and, while a job
runs, progress. Segments are buffered and played (``controller_job``) at ``dt_s`` from the start of segment 0,
``speed`` times faster than real time when asked, once a start buffer of motion is held. Each commanded posture
goes to a plant (``plant``): ``kinematic`` replays it; ``physics``, the MuJoCo twin, returns the measured state, a
balance stream and its faults (fall, foot tilt or lift, torque saturation). Like a real controller it trusts
nothing (docs/robot_bridge.md, the integrator's checklist, of which this simulator is the reference): signatures
and receipt deadlines (``controller_auth``), one job at a time in sequence, never a job it ended, the dead-man on
the dispatcher's heartbeat (judged on this process's monotonic clock at receipt), its own joint limits and
continuity, every stop at once. Fault injection for tests and demos: dropped or delayed commands, a crash after N
accepted segments, a frozen heartbeat. This module must not import the planner.
"""

from __future__ import annotations

import json
import os
import queue
import sys
import threading
import time
from typing import Callable

import numpy as np
import zenoh
from pydantic import ValidationError

from schemas.bridge import ENDED_BY_CONTROLLER, CommandHeartbeat, ExecStatus, Heartbeat, JointState, Stop, TrajectorySegment

from .controller_auth import CommandAuth
from .controller_job import Job, segment_columns
from .controller_settings import ControllerSimSettings, JointLimits, PlantKind, control_period, limits_from_urdf
from .plant import KinematicPlant, Plant, PlantFault
from .process_tuning import raise_thread_priority
from .settings import BridgeSettings, Keys
from .signing import Verifier
from .zenoh_session import control_publisher, encode, open_session, telemetry_publisher

__all__ = ["ControllerSim", "ControllerSimSettings", "JointLimits", "PlantKind", "limits_from_urdf"]

#: Exit code of an injected crash.
CRASH_EXIT_CODE = 3
#: The shortest pause between control ticks, s (when a tick overran its period).
MIN_TICK_PAUSE_S = 0.0005
#: Jobs remembered as ended (their segments refused), most recent first out when full.
ENDED_JOBS_KEPT = 10_000
#: The statuses with which this controller ends a running job (repeated in its heartbeat while it holds).
ENDING_STATUSES = frozenset({"stopped", "fault", "starved"})
#: Period of the state/balance stream, s (CONTRACT 6: 50 Hz or more).
BALANCE_PERIOD_S = 0.02


class ControllerSim:
    """The simulated controller; ``start()`` then ``wait()``; ``close()`` ends it cleanly."""

    def __init__(self, bridge: BridgeSettings, sim: ControllerSimSettings, joint_names: list[str], q0: np.ndarray,
                 limits: JointLimits, *, exit_fn: Callable[[int], None] = os._exit, verifier: Verifier | None = None,
                 log: Callable[[str], None] | None = None, plant: Plant | None = None):
        if len(joint_names) != len(q0):
            raise ValueError(f"{len(joint_names)} joint names for {len(q0)} initial values")
        if not np.all(np.isfinite(q0)):
            raise ValueError("the initial posture is not finite")
        self.bridge, self.sim = bridge, sim
        self.keys = Keys(bridge.robot_id)
        self.joint_names = list(joint_names)
        self._col = {n: i for i, n in enumerate(joint_names)}
        self.q_cmd = np.array(q0, dtype=float)  # the posture commanded now (held when a job ends)
        self.plant: Plant = plant if plant is not None else KinematicPlant(self.q_cmd)
        self.q = self.plant.measured().copy()  # the measured posture, as reported
        self.limits = limits
        self._exit = exit_fn
        self._lock = threading.Lock()
        self._inbox: queue.Queue = queue.Queue()
        self._closing = threading.Event()
        self._job: Job | None = None
        self._ended: dict[str, str] = {}  # job id -> how it ended; their segments are refused
        #: (job id, status, reason) of the last job this controller ended, repeated in its heartbeat while it holds:
        #: a dispatcher that missed the state/exec report (frozen, reconnected) learns the end from it.
        self._last_end: tuple[str, str, str] | None = None
        self._auth = CommandAuth(verifier, bridge.clock_skew_s, sim.max_expiry_ahead_s)
        self._log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self._holding = sim.holding
        self._accepted = 0
        self._first_accept: float | None = None
        self._fault: PlantFault | None = None  # the plant's first fault: nothing is played after it
        self.overruns = 0  # control ticks whose plant work took longer than their period
        self._rng = np.random.default_rng(sim.seed)
        self._threads: list[threading.Thread] = []
        self._session: zenoh.Session | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        s = self._session = open_session(self.bridge)
        self._pub_joints = telemetry_publisher(s, self.keys.joints)
        self._pub_balance = telemetry_publisher(s, self.keys.balance)
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

    def _open(self, payload: bytes, kind: str, received: float) -> dict | None:
        """The message as a dict if it is signed by the trusted key and within its deadline; else refused (None)."""
        msg, problem = self._auth.open(payload)
        if not isinstance(msg, dict):
            self._status(None, None, "refused", f"malformed {kind}: not a JSON object", received, kind=kind, fatal=False)
            return None
        if problem is not None:
            job_id = msg.get("job_id") if isinstance(msg.get("job_id"), str) else None
            seq = msg.get("seq") if isinstance(msg.get("seq"), int) and not isinstance(msg.get("seq"), bool) else None
            # Not fatal: nothing changed for a running job (a forged or late copy is not the dispatcher's word).
            self._status(job_id, seq, "refused", f"{kind} refused: {problem}", received, kind=kind, fatal=False)
            return None
        return msg

    # ------------------------------------------------------------------ commands
    def _handle_stop(self, payload: bytes, received: float) -> None:
        """Obeyed whatever it carries (stopping is always safe); whether it was signed is logged."""
        try:
            raw = json.loads(payload)
        except (ValueError, UnicodeDecodeError):
            raw = None
        auth = self._auth.stop_auth(raw)
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

    def _end(self, job: Job, state: str) -> int:
        """End a job (lock held): nothing more of it is played; its buffered points are dropped. Returns how many."""
        job.state = state
        dropped = job.drop()
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

    def _dead_man(self, job: Job, now: float) -> tuple[str, str, int]:
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
                reply = ("refused", f"job {seg.job_id} {ENDED_BY_CONTROLLER} ({self._ended[seg.job_id]}); "
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
                    reply = job.accept(seg, self.q, self.limits, self.joint_names, self.sim)  # own checks
            elif job is not None and job.state == "executing":
                reply = ("refused", f"another job is running: {job.job_id}")
            elif seg.segment_index != 0:
                reply = ("refused", f"out of sequence: job {seg.job_id} must start with segment 0, got "
                                    f"{seg.segment_index}")
                fatal = False  # segment 0 may still come (it is sent again)
            else:
                columns, problem = segment_columns(seg, self._col, self.joint_names)
                if problem:
                    reply = ("rejected", problem)
                elif self._fault is not None:
                    reply = ("rejected", f"the robot faulted ({self._fault.reason}); nothing more is played")
                else:
                    new = Job(seg, columns)
                    reply = new.accept(seg, self.q, self.limits, self.joint_names, self.sim)
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

    # ------------------------------------------------------------------ control loop
    def _control_loop(self) -> None:
        period, every = control_period(self.sim)
        next_tick = time.monotonic()
        tick = 0
        next_heartbeat = next_balance = next_progress = next_tick
        beats = 0
        while not self._closing.is_set():
            now = time.monotonic()
            with self._lock:
                job = self._job
                events, commands = self._commands(job, period * self.sim.speed, now)
            fault = self._drive(commands)  # the plant's work outside the lock: commands and heartbeats never wait
            with self._lock:
                if fault is not None:
                    if job is not None and job.state == "executing":
                        self._end(job, "fault")
                    events.append(("fault", fault.reason))
                q = self.q.copy()
                holding = self._holding
                job_id = job.job_id if job is not None else None
                index = job.index if job is not None else None
                executing = job is not None and job.state == "executing"
                stopped = job is not None and job.state in ("stopped", "starved", "fault", "rejected")
                seq = job.last_seq if job is not None else None
            for status, reason in events:
                self._status(job_id, seq, status, reason, None, index)
            if tick % every == 0:  # CONTRACT 7: >= 50 measured states per second of motion at any speed
                self._pub_joints.put(encode(JointState(stamp=now, joint_names=self.joint_names, q=q.tolist(),
                    job_id=job_id if executing else None, index=index if executing else None, stance=self.sim.stance,
                    holding=holding)))
            tick += 1
            balance = self.plant.balance() if now >= next_balance else None
            if balance is not None:
                self._pub_balance.put(encode({"stamp": now, **balance, "overruns": self.overruns}))
                next_balance = now + BALANCE_PERIOD_S
            if executing and now >= next_progress:
                self._status(job_id, seq, "executing", "", None, index)
                next_progress = now + self.sim.progress_period_s
            if now >= next_heartbeat and not self._heartbeat_frozen(now):
                state = "executing" if executing else ("holding" if stopped else "idle")
                end = self._last_end if stopped and self._last_end and self._last_end[0] == job_id else None
                self._pub_heartbeat.put(encode(Heartbeat(controller_id=self.sim.controller_id, count=beats, stamp=now,
                                                         state=state, job_id=job_id, status=end and end[1],
                                                         reason=end[2] if end else "")))
                beats += 1
                next_heartbeat = now + self.bridge.heartbeat_period_s
            next_tick += period
            sleep = next_tick - time.monotonic()
            if sleep > 0:
                time.sleep(sleep)
            else:
                self.overruns += 1  # the plant could not keep up: the next tick runs late, no step is skipped
                next_tick = time.monotonic()  # fell behind: do not try to catch up in a burst
                # Never a tick without a pause: at real-time priority a loop that fell behind must not hold the core.
                time.sleep(MIN_TICK_PAUSE_S)

    def _commands(self, job: Job | None, step: float, now: float) -> tuple[list[tuple[str, str]], list[tuple]]:
        """One control tick's decisions (lock held): the dead-man first (after a freeze nothing is played before the
        gap is judged), then ``step`` plan seconds of playback, cut into the plant's control steps: the events and
        the (posture, holding, duration) commands for the plant."""
        events: list[tuple[str, str]] = []
        running = job is not None and job.state == "executing"
        if running and job.last_heartbeat is not None and now - job.last_heartbeat > self.bridge.watchdog_timeout_s:
            events.append(self._dead_man(job, now)[:2])
            running = False
        if running and not job.playing and (running := job.ready(now, self.sim)):
            self.plant.on_playback(job.object_mass_kg)
        commands = []
        for dt in self.plant.substeps(step):
            if running and self._fault is None:
                q, holding, event = job.advance(dt, self.limits, self.sim.position_tolerance)
                if q is not None:
                    self.q_cmd = q
                    self._holding = holding or self._holding
                if event is not None:
                    self._end(job, event[0])
                    events.append(event)
                    running = False
            commands.append((self.q_cmd, self._holding, dt))
        return events, commands

    def _drive(self, commands: list[tuple]) -> PlantFault | None:
        """Play the commands on the plant; its first fault (once) ends playback, the posture held as measured."""
        first = None
        for q_cmd, holding, dt in commands:
            fault = self.plant.step(q_cmd, holding, dt)
            if fault is not None and self._fault is None:
                self._fault = first = fault
                self.q_cmd = self.plant.measured().copy()
        self.q = self.plant.measured().copy()
        return first

    def _heartbeat_frozen(self, now: float) -> bool:
        after = self.sim.freeze_heartbeat_after_s
        return after is not None and self._first_accept is not None and now - self._first_accept >= after

    def _status(self, job_id: str | None, seq: int | None, status: str, reason: str, received: float | None,
                index: int | None = None, fatal: bool = True, kind: str | None = "trajectory") -> None:
        if status == "refused":
            self._log(json.dumps({"event": "refused", "kind": kind, "job_id": job_id, "seq": seq, "reason": reason}))
        if (status in ENDING_STATUSES and fatal and job_id is not None
                and (self._last_end is None or self._last_end[0] != job_id)):
            self._last_end = (job_id, status, reason)  # the first end reported for the job is its end
        if self._session is None:
            return
        self._pub_exec.put(encode(ExecStatus(job_id=job_id, seq=seq, index=index, status=status, reason=reason,
                                             received_at=received, fatal=fatal, kind=kind)))
