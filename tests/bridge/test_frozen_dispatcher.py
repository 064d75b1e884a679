"""The controller's own stop is the job's truth, even when the dispatcher was frozen through it.

The dispatcher runs in its own process (as in the service: robot_bridge.dispatcher_process) against a real
controller-sim with the production 250 ms dead-man. Mid-execution the dispatcher's process is frozen with
SIGSTOP for longer than the zenoh lease, so the controller stops by itself, reports ``stopped`` while nobody
listens, and drops the link. On SIGCONT the execution must end ``aborted`` with the controller's reason (its
dead-man), not a loss or a progress timeout of the dispatcher's own making, within 1 s of the resume.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from robot_bridge.dispatcher_process import DispatcherProcess
from robot_bridge.settings import BridgeSettings

from .conftest import approval_for

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
        assert res.status == "aborted", res.reason
        assert res.reason.startswith("controller stopped: dead-man"), res.reason
        assert out["at"] - resumed < RESOLVE_S, (out["at"] - resumed, res.reason)
        assert res.last_index is not None and res.last_index < len(long_plan["trajectory"]) - 1
    finally:
        disp.close()
