"""The controller's own stop is the job's truth, even when the dispatcher was frozen through it.

The dispatcher runs in its own process (as in the service: robot_bridge.dispatcher_process) against a real
controller-sim with the production 250 ms dead-man. Mid-execution the dispatcher's process is frozen with
SIGSTOP for longer than the zenoh lease, so the controller stops by itself, reports ``stopped`` while nobody
listens, and drops the link. On SIGCONT the execution must end ``aborted`` with the controller's reason (its
dead-man), not a loss or a progress timeout of the dispatcher's own making, within 1 s of the resume.
"""

from __future__ import annotations

import os
import queue
import signal
import threading
import time
from typing import Any, Callable

import pytest
import zenoh
from pydantic import ValidationError

from robot_bridge import dispatcher as dispatcher_module
from robot_bridge.dispatch_types import DispatchSettings
from robot_bridge.dispatch_watch import ControllerWatch
from robot_bridge.dispatcher import Dispatcher
from robot_bridge.dispatcher_process import DispatcherProcess
from robot_bridge.settings import BridgeSettings
from schemas.bridge import ENDED_BY_CONTROLLER, ExecStatus, Heartbeat, TrajectorySegment

from .conftest import approval_for
from .test_fault_matrix import Recorder

#: A host that pauses the whole VM for this long measures the host, not the dispatcher; the test runs again.
pytestmark = pytest.mark.host_pauses(limit_s=0.3)

#: The freeze: longer than the zenoh lease (1 s), so the controller drops the frozen peer's link.
FREEZE_S = 2.5
#: The contract: the job ends aborted with the controller's reason within 1 s (of the resume, when frozen).
RESOLVE_S = 1.0


@pytest.mark.parametrize("freeze_s", [FREEZE_S, 4.0, 0.6])  # 4 s: past the 3 s progress timeout too
def test_a_frozen_dispatcher_ends_the_job_with_the_controllers_own_stop(spawn_controller, key_pair, long_plan,
                                                                        freeze_s):
    ctl = spawn_controller(speed=1.0, watchdog_s=0.25)
    disp = DispatcherProcess(BridgeSettings(robot_id=ctl.robot_id, connect=[ctl.endpoint], watchdog_timeout_s=0.5,
                                            signing_key=key_pair.private))
    try:
        assert disp.wait_for_controller(10.0), disp.controller_problem()
        sha, exp = approval_for(long_plan)
        events: list[tuple[float, str, dict]] = []
        executing = threading.Event()
        out: dict = {}

        def on_event(kind: str, data: dict) -> None:
            events.append((time.monotonic(), kind, data))
            if kind == "executing" and data.get("status") == "executing":  # the controller is playing it
                executing.set()

        def run() -> None:
            out["result"] = disp.execute(long_plan, job_id="frozen-job", approved_sha256=sha, approval_expires_at=exp,
                                         on_event=on_event)
            out["at"] = time.monotonic()

        runner = threading.Thread(target=run, daemon=True)
        runner.start()
        assert executing.wait(20.0), [k for _, k, _ in events]
        pid = disp._proc.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(freeze_s)
        finally:
            os.kill(pid, signal.SIGCONT)
            resumed = time.monotonic()
        runner.join(15.0)
        res = out["result"]
        # What the execution reported from just before the resume on, seconds from the resume: where the reason or
        # the time is wrong, this says what the thawed dispatcher saw and when (the controller back, or not).
        after = [(round(t - resumed, 3), k, d) for t, k, d in events if t >= resumed - 0.1]
        assert res.status == "aborted", (res.reason, after)
        assert res.reason.startswith("controller stopped: dead-man"), (res.reason, after)
        assert out["at"] - resumed < RESOLVE_S, (out["at"] - resumed, res.reason, after)
        assert res.last_index is not None and res.last_index < len(long_plan["trajectory"]) - 1
    finally:
        disp.close()


# --------------------------------------------------------------------------- the controller's report behind its refusal

#: The job of the test below, and how long after the execution loop took the controller's refusal of its re-sent
#: segment the controller's own report of its end (its heartbeat while it holds) reaches the dispatcher.
LATE_JOB = "late-report-job"
REPORT_LATE_S = 0.15


class _TakenQueue(queue.Queue):
    """The watch's ``state/exec`` queue; calls ``on_taken(status)`` for each status the execution loop takes."""

    def __init__(self, on_taken: Callable[[ExecStatus], None]):
        super().__init__()
        self.on_taken = on_taken

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        item = super().get(block, timeout)
        self.on_taken(item[1])
        return item


class _LateOwnReportWatch(ControllerWatch):
    """The watch of a dispatcher that was frozen while the controller stopped ``LATE_JOB`` (the race of the thawed
    bridge): the controller's ``state/exec`` report of its stop is missed (it calls ``on_own_stop`` instead), and its
    heartbeats saying it holds after ending the job arrive only ``REPORT_LATE_S`` after the execution loop took the
    refusal of a segment re-sent after that stop."""

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.exec = _TakenQueue(self._taken)
        self.on_own_stop: Callable[[], None] = lambda: None
        self.own_stop_missed = False
        self.released = threading.Event()
        self.released_at: float | None = None
        self.refusal_taken_at: float | None = None

    def _taken(self, st: ExecStatus) -> None:
        if (st.job_id == LATE_JOB and st.status == "refused" and ENDED_BY_CONTROLLER in st.reason
                and self.refusal_taken_at is None):
            self.refusal_taken_at = time.monotonic()
            threading.Timer(REPORT_LATE_S, self._release).start()

    def _release(self) -> None:
        self.released_at = time.monotonic()
        self.released.set()

    def on_exec(self, sample: zenoh.Sample) -> None:
        try:
            st = ExecStatus.model_validate_json(sample.payload.to_bytes())
        except ValidationError:
            return
        if st.job_id == LATE_JOB and st.status == "stopped" and not self.own_stop_missed:
            self.own_stop_missed = True  # missed while frozen; the thaw re-sends a segment
            threading.Thread(target=self.on_own_stop, daemon=True).start()
            return
        super().on_exec(sample)

    def on_heartbeat(self, sample: zenoh.Sample) -> None:
        try:
            beat = Heartbeat.model_validate_json(sample.payload.to_bytes())
        except ValidationError:
            return
        if beat.job_id == LATE_JOB and beat.state == "holding" and not self.released.is_set():
            return  # the controller's own report, not yet here
        super().on_heartbeat(sample)


class _ThawedDispatcher(Dispatcher):
    """Its heartbeat stops 0.5 s into the job (the controller's dead-man stops the robot, as for a frozen bridge);
    once the controller's stop is missed, the last segment it sent goes again (as after the thaw)."""

    _watch: _LateOwnReportWatch

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.last_sent: TrajectorySegment | None = None
        self._watch.on_own_stop = self._resend_last

    def _publish_segment(self, seg: TrajectorySegment) -> None:
        super()._publish_segment(seg)
        self.last_sent = seg

    def _begin_heartbeat(self, job_id: str) -> None:
        super()._begin_heartbeat(job_id)
        threading.Timer(0.5, self._end_heartbeat).start()

    def _resend_last(self) -> None:
        if self.last_sent is not None:
            self._publish_segment(self.last_sent)


def test_a_refusal_for_the_controllers_own_end_waits_for_its_own_report(bridge, long_plan, monkeypatch):
    """The controller refuses a segment re-sent after it stopped the job by itself ("... was ended by this
    controller (stopped)"), and its own report of that stop (its heartbeat while it holds) reaches the dispatcher
    only after the execution loop took the refusal. The job ends with the controller's own stop (its dead-man),
    not with the refusal: the loop waits, for ``resync_s`` at most, for that report."""
    monkeypatch.setattr(dispatcher_module, "ControllerWatch", _LateOwnReportWatch)
    ctl, disp, spy = bridge(speed=1.0, dispatcher_cls=_ThawedDispatcher, controller_watchdog_s=0.25)
    watch = disp._watch
    assert isinstance(watch, _LateOwnReportWatch)
    sha, exp = approval_for(long_plan)
    rec = Recorder()
    res = disp.execute(long_plan, job_id=LATE_JOB, approved_sha256=sha, approval_expires_at=exp, on_event=rec)
    ended_at = time.monotonic()
    refused = [d for d in rec.controller()
               if d["status"] == "refused" and ENDED_BY_CONTROLLER in (d.get("reason") or "")]
    assert refused and "(stopped)" in refused[0]["reason"], rec.controller()
    assert watch.refusal_taken_at is not None  # the loop took the refusal before the controller's own report
    assert res.status == "aborted", res.reason
    assert res.reason.startswith("controller stopped: dead-man"), res.reason
    # Judged once the report came, and within the bounded wait of the refusal.
    assert watch.released_at is not None and watch.released_at <= ended_at
    assert ended_at - watch.refusal_taken_at < DispatchSettings().resync_s + 0.5
