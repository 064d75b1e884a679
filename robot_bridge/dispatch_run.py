"""The dispatcher's execution state machine: send a gate-passed plan's segments and follow the controller.

Part of the dispatcher (:mod:`robot_bridge.dispatcher`). Segments (<= 1 s of points each) go out a few
ahead of the controller's progress, at most a window of them unacknowledged; a refused gap is re-sent at
once, an unacknowledged segment after ``resend_after_s``. An execution ends ``succeeded`` when the
controller says so, and ``aborted`` on an operator's stop, a lost controller (:mod:`robot_bridge.dispatch_watch`),
the controller's own stop or fault, or no progress; every abort sends ``cmd/stop``.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

from schemas.bridge import ENDED_BY_CONTROLLER, ExecStatus, GateVerdict, TrajectorySegment

from .dispatch_io import DispatcherIO
from .dispatch_types import DispatchSettings, EventCallback, ExecutionResult, SignedSegment
from .dispatch_watch import ControllerWatch, HeartbeatSender, LossWatch
from .process_tuning import bridge_priority
from .settings import BridgeSettings
from .signing import Signer

@dataclass
class _Run:
    """One execution's progress: what was sent, what the controller acknowledged and reached."""

    job_id: str
    segments: list[TrajectorySegment]
    seqs: frozenset[int] = frozenset()
    sent: int = 0
    index: int | None = None
    pending: dict[int, tuple[float, int]] = field(default_factory=dict)  # seq -> (last sent, re-sends)
    last_new_at: float = -math.inf  # when a segment last went out for the first time
    gap_resent_at: float = -math.inf  # when a refusal for a gap last started a re-send


class Execution:
    """Follows one gate-passed execution to its end; :meth:`follow` runs on the caller's thread."""

    def __init__(self, settings: BridgeSettings, pacing: DispatchSettings, io: DispatcherIO, watch: ControllerWatch,
                 heartbeat: HeartbeatSender, loss: LossWatch, signer: Signer, stop_requested: Callable[[str], bool],
                 publish: Callable[[TrajectorySegment], None] | None = None,
                 begin_heartbeat: Callable[[str], None] | None = None):
        self.settings = settings
        self.pacing = pacing
        self.io = io
        self.watch = watch
        self.heartbeat = heartbeat
        #: Judges the controller's loss and sends the stop on a thread of its own (off this loop's path).
        self.loss = loss
        self.signer = signer
        #: Whether an operator asked to stop this job (or every job) since it started.
        self.stop_requested = stop_requested
        #: How a segment goes out and how the heartbeat starts (the dispatcher's hooks; by default
        #: :meth:`put_segment` and :meth:`HeartbeatSender.begin`).
        self.publish = publish or self.put_segment
        self.begin_heartbeat = begin_heartbeat or heartbeat.begin
        self._payloads: dict[int, SignedSegment] = {}  # seq -> segment ready to sign, of the running execution only

    def send_segment(self, run: _Run, emit: EventCallback) -> None:
        seg = run.segments[run.sent]
        sent_at = time.monotonic()
        self.publish(seg)
        if run.sent == 0:
            self.begin_heartbeat(run.job_id)  # the controller arms its dead-man at this segment
        run.pending[seg.seq] = (sent_at, 0)
        run.last_new_at = sent_at
        run.sent += 1
        emit("segment", {"job_id": run.job_id, "seq": seg.seq, "segment_index": seg.segment_index,
                         "segment_count": seg.segment_count, "first_index": seg.first_index, "points": len(seg.points),
                         "t_from_start": seg.t_from_start, "sent_at": sent_at})

    def _resend(self, run: _Run, emit: EventCallback, now: float, due: Callable[[float], bool], cause: str) -> None:
        """Send again the unacknowledged segments whose last send is ``due`` (same seq: the controller drops
        duplicates). The controller refuses whatever comes after a gap, so the segments behind the oldest
        unacknowledged one go again with it, but only that one spends its re-send budget: they were refused
        for its loss, and a budget spent on that would be gone when they become the gap."""
        d = self.pacing
        waiting = sorted(run.pending.items())
        head = waiting[0][0] if waiting else None
        for seq, (sent_at, count) in waiting:
            if due(sent_at) and (count < d.max_resends or seq != head):
                self.publish(run.segments[seq - run.segments[0].seq])
                spent = count + 1 if seq == head else count
                run.pending[seq] = (now, spent)
                emit("segment", {"job_id": run.job_id, "seq": seq, "resent": spent, "behind_gap": seq != head,
                                 "cause": cause})

    def controllers_own_end(self, job_id: str, st: ExecStatus, since: float) -> tuple[str, str] | None:
        """``(status, reason)`` of the controller's own end of ``job_id`` (its heartbeat while it holds, received
        after ``since``), judged for its fatal refusal ``st`` of one of the job's segments; None when there is none.

        A refusal because the controller had already ended the job can be judged before the controller's own
        report: after a freeze of this process its ``state/exec`` report of the end was missed, and its heartbeat
        saying so can come just behind the refusal of a segment re-sent on the thaw. For such a refusal only, that
        heartbeat is awaited for ``resync_s`` at most (the time the controller is given to be heard from after a
        freeze); other refusals are judged on what is known now."""
        ended = self.watch.controller_ended(job_id, since=since)
        if ended is not None or st.status != "refused" or ENDED_BY_CONTROLLER not in st.reason:
            return ended
        deadline = time.monotonic() + self.pacing.resync_s
        while ended is None and time.monotonic() < deadline:
            time.sleep(self.pacing.poll_period_s)
            ended = self.watch.controller_ended(job_id, since=since)
        return ended

    def put_segment(self, seg: TrajectorySegment) -> None:
        """Put one segment of the running execution on ``cmd/trajectory`` (the only place that does), as serialised
        when the gate passed the plan, with its receipt deadline and signature of now."""
        assert self.signer is not None
        self.io.put_segment(self._payloads[seg.seq].wire(self.signer, time.time() + self.settings.segment_expiry_s))

    def _abort(self, run: _Run, emit: EventCallback, reason: str, verdict: GateVerdict, started: float,
               wait_ack: bool = False) -> ExecutionResult:
        # The heartbeat ends first: should the stop not arrive, the controller's dead-man stops the robot.
        self.heartbeat.end()
        if self.loss.disarm() is None:  # else the loss watch has sent the stop and reported it
            self.io.send_stop(run.job_id, reason)
            emit("stop_sent", {"job_id": run.job_id, "reason": reason})
        acked = False
        if wait_ack:
            deadline = time.monotonic() + self.pacing.ack_timeout_s
            while time.monotonic() < deadline and not acked:
                try:
                    _, st = self.watch.exec.get(timeout=self.pacing.poll_period_s)
                except queue.Empty:
                    continue
                acked = st.status == "stopped"
                if st.index is not None:
                    run.index = st.index
        result = ExecutionResult("aborted", reason, verdict, run.index, run.sent, time.monotonic() - started,
                                 {"stop_acknowledged": acked} if wait_ack else {})
        self.report_measured(emit)
        emit("finished", result.to_dict())
        return result

    def report_measured(self, emit: EventCallback) -> None:
        """One ``robot_state`` event with every measured state received since the last one (``samples``, oldest
        first, each ``{stamp, q, index}``); the newest also at the top level, for readers of one state."""
        batch = self.watch.take_measured()
        if not batch:
            return
        last = batch[-1]
        emit("robot_state", {"stamp": last.stamp, "joint_names": last.joint_names, "q": last.q, "index": last.index,
                             "samples": [{"stamp": js.stamp, "q": js.q, "index": js.index} for js in batch]})

    def run(self, run: _Run, emit: EventCallback, stop_event: threading.Event, verdict: GateVerdict,
            started: float) -> ExecutionResult:
        """Follow ``run`` to its end; whatever breaks on the way, the robot is told to stop."""
        # Serialised once, now: a send (and a re-send) then only splices in its expires_at and signs.
        self._payloads = {seg.seq: SignedSegment(seg) for seg in run.segments}
        self.watch.collect_measured(True)
        try:
            # This loop takes the interpreter lock on the bridge's path: at the heartbeat's priority while it runs.
            with bridge_priority(self.settings.thread_nice, self.settings.realtime_priority):
                return self.follow(run, emit, stop_event, verdict, started)
        except Exception as exc:  # fail safe: whatever broke, the robot is told to stop
            self.heartbeat.end()
            self.io.send_stop(run.job_id, f"bridge error: {exc}")
            emit("stop_sent", {"job_id": run.job_id, "reason": f"bridge error: {exc}"})
            return ExecutionResult("aborted", f"bridge error: {type(exc).__name__}: {exc}", verdict, run.index, run.sent,
                                   time.monotonic() - started)
        finally:
            self.watch.collect_measured(False)
            self.loss.disarm()
            self.heartbeat.end()
            self._payloads = {}  # a finished execution's bytes are not kept until the next one

    def follow(self, run: _Run, emit: EventCallback, stop_event: threading.Event, verdict: GateVerdict,
               started: float) -> ExecutionResult:
        d = self.pacing
        ahead = d.lookahead_segments

        def window_open(now: float) -> bool:
            """Fewer than the window unacknowledged; or the oldest of them waited too long for its acknowledgement
            and no segment went out for as long (late acknowledgements let one more out per ``in_flight_wait_s``)."""
            if len(run.pending) < d.max_in_flight_segments:
                return True
            return (now - min(sent_at for sent_at, _ in run.pending.values()) > d.in_flight_wait_s
                    and now - run.last_new_at > d.in_flight_wait_s)

        # The controller's loss is judged by the loss watch (its own thread); this loop notes only its own long
        # stalls (a frozen process), after which it waits for the controller's word before sending again.
        last_iteration = run_started = time.monotonic()
        resync_until = -math.inf  # after a long stall of this process: the controller's word is awaited until then
        thawed_at = -math.inf  # when this process last ran again after such a stall
        self.loss.arm(run.job_id, emit)
        while run.sent < min(len(run.segments), ahead) and window_open(time.monotonic()):
            self.send_segment(run, emit)
        last_progress = time.monotonic()
        last_state_event = 0.0
        executing_announced = False
        per = len(run.segments[0].points)
        while True:
            if stop_event.is_set() or self.stop_requested(run.job_id):
                return self._abort(run, emit, "stopped by operator", verdict, started, wait_ack=True)
            tick = time.monotonic()
            if tick - last_iteration > self.settings.watchdog_timeout_s:
                resync_until, thawed_at = tick + d.resync_s, tick
            last_iteration = tick
            # The controller's own end of the job is the job's truth, however it reaches us: its state/exec report
            # (below) or, when that was missed, its heartbeat saying it holds after ending this job.
            ended = self.watch.controller_ended(run.job_id, since=run_started)
            if ended is not None:
                emit("controller", {"job_id": run.job_id, "status": ended[0], "reason": ended[1], "via": "heartbeat"})
                return self._abort(run, emit, f"controller {ended[0]}: {ended[1]}", verdict, started)
            lost = self.loss.lost()
            if lost is not None:
                return self._abort(run, emit, lost[0], verdict, started)
            try:
                at, st = self.watch.exec.get(timeout=d.poll_period_s)
            except queue.Empty:
                st = None
            now = time.monotonic()
            if now - last_iteration > self.settings.watchdog_timeout_s:  # frozen while it waited for a status
                resync_until, thawed_at = now + d.resync_s, now
            last_iteration = now
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
                    self.loss.disarm()
                    result = ExecutionResult("succeeded", st.reason or "trajectory executed", verdict, st.index, run.sent,
                                             now - started)
                    self.report_measured(emit)
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
                    # A refusal because the controller had already ended the job: its own end is the reason.
                    ended = self.controllers_own_end(run.job_id, st, since=run_started) \
                        if st.status in ("rejected", "refused") else None
                    status, reason = ended if ended is not None else (st.status, st.reason)
                    return self._abort(run, emit, f"controller {status}: {reason}", verdict, started)
            elif st is not None and st.status == "refused" and st.job_id is None:
                # An unreadable command refused: not this execution's (its segments name their job).
                emit("controller", {"job_id": run.job_id, "status": st.status, "reason": st.reason, "kind": st.kind})
            elif st is not None and st.status == "rejected" and st.job_id is None:
                emit("controller", {"job_id": run.job_id, "status": st.status, "reason": st.reason})
                return self._abort(run, emit, f"controller rejected a command: {st.reason}", verdict, started)
            # After a freeze, nothing goes out until the controller is heard from again: it may have ended the job
            # meanwhile, and its word on that (not a refusal of what we send next) is how the job ends.
            if not (now < resync_until and (self.watch.last_heartbeat_at() or -math.inf) < thawed_at):
                self._resend(run, emit, now, due=lambda sent_at: now - sent_at > d.resend_after_s, cause="timeout")
                # keep the controller fed: stay `lookahead` segments ahead of the one being played, at most
                # `max_in_flight_segments` of them unacknowledged unless an acknowledgement is late
                playing = (run.index or 0) // per
                while run.sent < len(run.segments) and run.sent <= playing + ahead and window_open(now):
                    self.send_segment(run, emit)
            if now - max(last_progress, thawed_at) > d.progress_timeout_s:
                return self._abort(run, emit, f"no progress from the controller for {d.progress_timeout_s:.1f} s", verdict, started)
            if now - last_state_event >= d.robot_state_event_period_s:
                self.report_measured(emit)
                last_state_event = now
