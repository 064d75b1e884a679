"""Dispatch through the real robot bridge to `regrasp controller-sim` on a private loopback endpoint.

The plans come from the `stand` test handler: real, gate-valid plans that hold the
upright stance posture (and one that the gate must veto), so the dispatch path is
tested whatever state the planner is in.
"""

from __future__ import annotations

from typing import Iterator

import pytest
from conftest import (Server, free_port, start_controller_sim, stop_process, submit_approved_plan,
                      wait_controller_alive, wait_state)

END_STATES = {"succeeded", "aborted", "rejected", "failed"}
CONTROLLER_UP_TIMEOUT_S = 60.0


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
        done = wait_state(bob, job_id, END_STATES, timeout=30)
        assert done["state"] == "succeeded", (done["message"], done["error"])
        history = bob.get(f"/v1/jobs/{job_id}/events", params={"follow": "false"}).text
        for expected in ('"event":"gate"', '"event":"segment"', '"state":"dispatching"', '"state":"executing"',
                         '"state":"succeeded"'):
            assert expected in history, expected


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
