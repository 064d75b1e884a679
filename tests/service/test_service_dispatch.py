"""Dispatch through the real robot bridge to `regrasp controller-sim` on a private loopback endpoint.

The plans come from the `stand` test handler: real, gate-valid plans that hold the
upright stance posture (and one that the gate must veto), so the dispatch path is
tested whatever state the planner is in.
"""

from __future__ import annotations

import os
import signal
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterator

import httpx
import pytest
from conftest import (
    BRIDGE_WATCHDOG_S,
    CONTROLLER_UP_TIMEOUT_S,
    END_STATES,
    Server,
    free_port,
    job_events,
    start_controller_sim,
    stop_process,
    submit_approved_plan,
    wait_controller_alive,
    wait_state,
)

#: Executions on the simulated controller in wall-clock time (a 2 s watchdog, a 3 s zenoh lease): a failure
#: while the VM's host paused the guest for 0.5 s or more measured the host, and the test runs again.
pytestmark = pytest.mark.host_pauses(limit_s=0.5)
#: Beyond the bridge's watchdog, what a loaded machine may take to notice the loss and store the abort, s.
LOSS_MARGIN_S = 3.0


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, int]]:
    port = free_port()
    srv = Server(tmp_path_factory.mktemp("dispatch"), workers=1, bridge_port=port).start()
    try:
        yield srv, port
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def sim(rig: tuple[Server, int]) -> Iterator[None]:
    srv, port = rig
    proc = start_controller_sim(srv.data_dir, port, speed=1)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        yield
    finally:
        stop_process(proc)


def _approved(srv: Server, scenario: str) -> str:
    return submit_approved_plan(srv, {"scenario": scenario})


def test_no_controller_409(rig: tuple[Server, int]) -> None:
    srv, _ = rig
    job_id = _approved(srv, "stand-1")
    with srv.client("bob") as bob:
        r = bob.post(f"/v1/jobs/{job_id}/dispatch")
        assert r.status_code == 409 and "no controller is alive" in r.json()["detail"]
        assert bob.get(f"/v1/jobs/{job_id}").json()["state"] == "approved"


def test_dispatch_executes_to_success(rig: tuple[Server, int], sim: None) -> None:
    srv, _ = rig
    job_id = _approved(srv, "stand-1")
    with srv.client("bob") as bob:
        r = bob.post(f"/v1/jobs/{job_id}/dispatch")
        assert r.status_code == 202 and r.json()["state"] in ("dispatching", "executing"), r.text
        assert "result" not in r.json() and len(r.content) < 8000  # the job's summary, not the plan
        done = wait_state(bob, job_id, END_STATES, timeout=30)
        assert done["state"] == "succeeded", (done["message"], done["error"])
        history = bob.get(f"/v1/jobs/{job_id}/events", params={"follow": "false"}).text
        for expected in ('"event":"gate"', '"event":"segment"', '"state":"dispatching"', '"state":"executing"',
                         '"state":"succeeded"'):
            assert expected in history, expected
    # a kinematic controller publishes no balance: the health says none has come
    assert httpx.get(srv.url + "/healthz", timeout=5).json()["balance_age_s"] is None


def test_operator_stop_aborts(rig: tuple[Server, int], sim: None) -> None:
    srv, _ = rig
    job_id = _approved(srv, "stand-10")
    with srv.client("bob") as bob, srv.client("alice") as alice:
        r = bob.post(f"/v1/jobs/{job_id}/dispatch")
        assert r.status_code == 202, r.text
        running = wait_state(bob, job_id, {"executing"} | END_STATES, timeout=30)
        assert running["state"] == "executing", (running["message"], running["error"])
        assert alice.post(f"/v1/jobs/{job_id}/stop").status_code == 403
        assert alice.post(f"/v1/jobs/{job_id}/cancel").status_code == 409
        r = bob.post(f"/v1/jobs/{job_id}/stop", json={"reason": "test"})
        assert r.status_code == 202, r.text
        done = wait_state(bob, job_id, END_STATES, timeout=10)
        assert done["state"] == "aborted" and done["error"]["code"] == "ABORTED", (done["message"], done["error"])


def test_gate_veto_rejects(rig: tuple[Server, int], sim: None) -> None:
    srv, _ = rig
    job_id = _approved(srv, "standbad-1")
    with srv.client("bob") as bob:
        assert bob.post(f"/v1/jobs/{job_id}/dispatch").status_code == 202
        done = wait_state(bob, job_id, END_STATES, timeout=30)
        assert done["state"] == "rejected" and done["error"]["code"] == "GATE_VETO"
        assert "joint_position" in done["error"]["message"] or "limit" in done["error"]["message"], done["error"]
        history = bob.get(f"/v1/jobs/{job_id}/events", params={"follow": "false"}).text
        assert '"event":"segment"' not in history  # nothing was sent


#: How each fault is made and the abort reason it must give. SIGKILL: the kernel closes the zenoh link, so
#: the controller's liveliness token goes at once. SIGSTOP: the link stays open but silent; the zenoh
#: lease (1 s by default, 3 s in the service tests) could drop it before the 2 s watchdog and its margin, so
#: both peers announce a 6 s lease here and the bridge's heartbeat watchdog is what must notice the stall.
FAULTS = {
    "killed": (signal.SIGKILL, {}, "controller lost: "),
    "stalled": (signal.SIGSTOP, {"bridge_lease_s": "6"}, "controller lost: controller heartbeat lost: "),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_controller_lost_mid_execution_aborts_the_job(tmp_path: Path, fault: str) -> None:
    """The controller-sim is killed or stalled while it plays a 10 s plan: the job ends aborted, naming the
    lost controller, within the watchdog and a margin."""
    sig, settings, reason = FAULTS[fault]
    port = free_port()
    srv = Server(tmp_path, workers=1, bridge_port=port, **settings).start()
    proc = start_controller_sim(srv.data_dir, port, speed=1, **settings)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        job_id = submit_approved_plan(srv, {"scenario": "stand-10"})
        with srv.client("bob") as bob:
            r = bob.post(f"/v1/jobs/{job_id}/dispatch")
            assert r.status_code == 202, r.text
            # Mid-execution: the controller has reported playing the plan.
            deadline = time.monotonic() + 30
            while not any(e["kind"] == "bridge" and e["data"].get("event") == "executing"
                          for e in job_events(bob, job_id)):
                assert time.monotonic() < deadline, bob.get(f"/v1/jobs/{job_id}").json()["state"]
                time.sleep(0.1)
            assert bob.get(f"/v1/jobs/{job_id}").json()["state"] == "executing"
            lost_at = datetime.now(timezone.utc)
            proc.send_signal(sig)
            done = wait_state(bob, job_id, END_STATES, timeout=30)
            assert done["state"] == "aborted", (done["message"], done["error"])
            assert done["error"]["code"] == "ABORTED" and done["error"]["message"].startswith(reason), done["error"]
            events = job_events(bob, job_id)
        states = [e["state"] for e in events if e["kind"] == "state"]
        assert states == ["queued", "planning", "planned", "approved", "dispatching", "executing", "aborted"]
        aborted = next(e for e in events if e["kind"] == "state" and e["state"] == "aborted")
        assert aborted["data"]["reason"] == done["error"]["message"]
        finished = [e["data"]["payload"] for e in events if e["kind"] == "bridge" and e["data"].get("event") == "finished"]
        assert [(f["status"], f["reason"]) for f in finished] == [("aborted", done["error"]["message"])]
        # Server time from the loss to the stored abort: the watchdog (or the dropped link) and a margin,
        # far short of the plan's 10 s.
        lost_for_s = (datetime.fromisoformat(aborted["at"]) - lost_at).total_seconds()
        assert 0.0 < lost_for_s < BRIDGE_WATCHDOG_S + LOSS_MARGIN_S, lost_for_s
    finally:
        proc.kill()  # a stopped process is killed too
        proc.wait(10)
        srv.stop()


def _bridge_process(srv: Server, controller_port: int) -> int:
    """The pid of the server's bridge process: its child connected to the controller's endpoint."""
    import psutil

    for child in psutil.Process(srv.proc.pid).children(recursive=True):
        try:
            if any(c.raddr and c.raddr.port == controller_port for c in child.net_connections(kind="tcp")):
                return child.pid
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
    raise AssertionError("no child of the server is connected to the controller")


def test_a_frozen_bridge_process_records_the_controllers_own_stop(tmp_path: Path) -> None:
    """The server's bridge process is frozen (SIGSTOP) mid-execution for longer than the controller's dead-man and
    the zenoh lease: the controller stops by itself while nobody listens. On SIGCONT the job ends aborted with the
    controller's own reason, within 1 s of the resume: its dead-man (no heartbeat), or its starvation where the
    segments it had been sent ran out first (which comes first depends on how far ahead the dispatcher had sent when
    it froze; both are the controller's own stop)."""
    port = free_port()
    srv = Server(tmp_path, workers=1, bridge_port=port).start()
    proc = start_controller_sim(srv.data_dir, port, speed=1)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        job_id = submit_approved_plan(srv, {"scenario": "stand-10"})
        with srv.client("bob") as bob:
            assert bob.post(f"/v1/jobs/{job_id}/dispatch").status_code == 202
            deadline = time.monotonic() + 30
            while not any(e["kind"] == "bridge" and e["data"].get("event") == "executing"
                          for e in job_events(bob, job_id)):
                assert time.monotonic() < deadline, bob.get(f"/v1/jobs/{job_id}").json()["state"]
                time.sleep(0.1)
            bridge = _bridge_process(srv, port)
            os.kill(bridge, signal.SIGSTOP)
            try:
                time.sleep(BRIDGE_WATCHDOG_S + 2.5)  # past the controller's dead-man and the 3 s lease
                assert bob.get(f"/v1/jobs/{job_id}").json()["state"] == "executing"  # nobody could know yet
            finally:
                os.kill(bridge, signal.SIGCONT)
                resumed = datetime.now(timezone.utc)
            done = wait_state(bob, job_id, END_STATES, timeout=30)
            assert done["state"] == "aborted", (done["message"], done["error"])
            assert done["error"]["message"].startswith(("controller stopped: dead-man", "controller starved:")), \
                done["error"]
            aborted = next(e for e in job_events(bob, job_id) if e["kind"] == "state" and e["state"] == "aborted")
        assert (datetime.fromisoformat(aborted["at"]) - resumed).total_seconds() < 1.0
    finally:
        proc.kill()
        proc.wait(10)
        srv.stop()
