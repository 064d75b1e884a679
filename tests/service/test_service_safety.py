"""Execution safety through the real service: one dispatch at a time, no dispatch without a signing key,
recovery after an abort, and the stop re-sent to a controller that was lost, each in the job's audit file.

Real ``regrasp serve`` processes and ``regrasp controller-sim`` on private loopback endpoints; the plans come
from the test handlers (``stand-S`` holds the upright posture, ``move-S`` swings an arm) and the recovery from
the real recovery planner.
"""

from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import httpx
import pytest
from conftest import (
    closed_audit_events,
    MCAP_MAGIC,
    BRIDGE_ROBOT_ID,
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
from mcap.reader import make_reader

#: Executions in wall-clock time on the simulated controller (2 s watchdogs): a failure while the VM's host
#: paused the guest for 0.5 s or more measured the host, and the test runs again.
pytestmark = pytest.mark.host_pauses(limit_s=0.5)
AUDIT_TIMEOUT_S = 20.0


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, Any]]:
    port = free_port()
    srv = Server(tmp_path_factory.mktemp("safety"), workers=1, bridge_port=port).start()
    proc = start_controller_sim(srv.data_dir, port, speed=1)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        yield srv, proc
    finally:
        stop_process(proc)
        srv.stop()


def _audit_events(srv: Server, job_id: str, want: str = "finished") -> list[tuple[str, dict[str, Any]]]:
    """The job's closed audit records once they hold a ``want`` record."""
    return closed_audit_events(srv, job_id, want, AUDIT_TIMEOUT_S)


def test_concurrent_dispatches_get_exactly_one_202(rig: tuple[Server, Any]) -> None:
    """Four dispatches at once (one job twice, two other approved jobs): one 202, three 409 naming the running job;
    the losers stay approved, and no one was told a dispatch was accepted that did not run."""
    srv, _ = rig
    a, b, c = (submit_approved_plan(srv, {"scenario": "stand-2"}) for _ in range(3))
    results: dict[int, httpx.Response] = {}
    barrier = threading.Barrier(4)

    def dispatch(i: int, job_id: str) -> None:
        with srv.client("bob") as bob:
            barrier.wait()
            results[i] = bob.post(f"/v1/jobs/{job_id}/dispatch")

    threads = [threading.Thread(target=dispatch, args=(i, j)) for i, j in enumerate([a, a, b, c])]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    codes = sorted(r.status_code for r in results.values())
    assert codes == [202, 409, 409, 409], [(r.status_code, r.text) for r in results.values()]
    winner = next(r.json()["id"] for r in results.values() if r.status_code == 202)
    for r in results.values():
        if r.status_code == 409:
            assert winner in r.json()["detail"], r.json()["detail"]
    with srv.client("bob") as bob:
        done = wait_state(bob, winner, END_STATES, timeout=30)
        assert done["state"] == "succeeded", (done["message"], done["error"])
        for job_id in {a, b, c} - {winner}:
            assert bob.get(f"/v1/jobs/{job_id}").json()["state"] == "approved"
            states = [e["state"] for e in job_events(bob, job_id) if e["kind"] == "state"]
            assert "dispatching" not in states


def test_recovery_after_an_abort_then_a_normal_plan_succeeds(rig: tuple[Server, Any]) -> None:
    srv, _ = rig
    moving = submit_approved_plan(srv, {"scenario": "move-4"})
    with srv.client("bob") as bob, srv.client("carol") as carol:
        assert bob.post(f"/v1/jobs/{moving}/dispatch").status_code == 202
        wait_state(bob, moving, {"executing"} | END_STATES, timeout=30)
        time.sleep(1.5)  # mid-swing
        assert bob.post(f"/v1/jobs/{moving}/stop", json={"reason": "test"}).status_code == 202
        done = wait_state(bob, moving, END_STATES, timeout=10)
        assert done["state"] == "aborted", (done["message"], done["error"])

        # Left mid-motion: a plan made from the stance posture is vetoed at its start state.
        stand = submit_approved_plan(srv, {"scenario": "stand-1"})
        assert bob.post(f"/v1/jobs/{stand}/dispatch").status_code == 202
        vetoed = wait_state(bob, stand, END_STATES, timeout=30)
        assert vetoed["state"] == "rejected" and "start_state" in vetoed["error"]["message"], vetoed["error"]
        assert "the way out: plan the way back" in vetoed["error"]["message"]  # the veto names the way out

        # A recover job (an operator's) from the measured state back to the stance posture.
        assert carol.post("/v1/jobs", json={"kind": "recover", "request": {"robot": BRIDGE_ROBOT_ID}}).status_code == 403
        r = bob.post("/v1/jobs", json={"kind": "recover", "request": {"robot": "elsewhere"}})
        assert r.status_code == 422 and "elsewhere" in r.json()["detail"]
        r = bob.post("/v1/jobs", json={"kind": "recover", "request": {"robot": BRIDGE_ROBOT_ID}})
        assert r.status_code == 202, r.text
        recover = r.json()["id"]
        measured = r.json()["request"]["measured"]
        assert measured["stance"] == "upright" and measured["holding"] == "none"
        planned = wait_state(bob, recover, {"planned", "failed"}, timeout=120)
        assert planned["state"] == "planned", planned["error"]
        plan = planned["result"]
        assert plan["schema"] == "regrasp.plan/1" and plan["status"] == "solved"
        by_name = dict(zip(measured["joint_names"], measured["q"]))
        assert plan["trajectory"][0]["q"] == [by_name[n] for n in plan["robot"]["joint_names"]]
        # two-person rule and approval as for any plan
        assert bob.post(f"/v1/jobs/{recover}/approve", json={"plan_sha256": planned["plan_sha256"]}).status_code == 403
        assert carol.post(f"/v1/jobs/{recover}/approve", json={"plan_sha256": planned["plan_sha256"]}).status_code == 200
        assert bob.post(f"/v1/jobs/{recover}/dispatch").status_code == 202
        recovered = wait_state(bob, recover, END_STATES, timeout=60)
        assert recovered["state"] == "succeeded", (recovered["message"], recovered["error"])

        # Back in the stance posture: the next plan dispatches and succeeds.
        again = submit_approved_plan(srv, {"scenario": "stand-1"})
        assert bob.post(f"/v1/jobs/{again}/dispatch").status_code == 202
        ok = wait_state(bob, again, END_STATES, timeout=30)
        assert ok["state"] == "succeeded", (ok["message"], ok["error"])

    # Every ending is in the job's audit file.
    aborted = _audit_events(srv, moving)
    kinds = [k for k, _ in aborted]
    assert "stop_sent" in kinds and ("finished", "aborted") in [(k, p["data"].get("status")) for k, p in aborted
                                                                  if k == "finished"]
    assert [p["state"] for k, p in aborted if k == "state"][-1] == "aborted"
    veto = _audit_events(srv, stand, want="gate_verdict")
    assert [p["state"] for k, p in veto if k == "state"][-1] == "rejected"
    assert any(k == "gate_verdict" and p["verdict"]["check"] == "start_state" for k, p in veto)
    rec = _audit_events(srv, recover)
    assert "plan" in [k for k, _ in rec] and [p["state"] for k, p in rec if k == "state"][-1] == "succeeded"


def test_a_recovery_while_holding_carries_the_object_of_the_aborted_plan(rig: tuple[Server, Any]) -> None:
    """Stopped mid-swing holding 3 kg: the controller reports what it holds, the recover job takes the object's
    mass and pose from the aborted plan at the index the controller reached, and the recovery executes."""
    srv, _ = rig
    moving = submit_approved_plan(srv, {"scenario": "moveheld-4"})
    with srv.client("bob") as bob, srv.client("carol") as carol:
        assert bob.post(f"/v1/jobs/{moving}/dispatch").status_code == 202
        wait_state(bob, moving, {"executing"} | END_STATES, timeout=30)
        time.sleep(1.5)
        assert bob.post(f"/v1/jobs/{moving}/stop").status_code == 202
        assert wait_state(bob, moving, END_STATES, timeout=10)["state"] == "aborted"
        time.sleep(0.3)
        r = bob.post("/v1/jobs", json={"kind": "recover", "request": {"robot": BRIDGE_ROBOT_ID}})
        assert r.status_code == 202, r.text
        request = r.json()["request"]
        assert request["measured"]["holding"] == "right"
        assert request["object"]["mass_kg"] == 3.0 and request["object"]["from_job"] == moving
        recover = r.json()["id"]
        planned = wait_state(bob, recover, {"planned", "failed"}, timeout=120)
        assert planned["state"] == "planned", planned["error"]
        assert {p["holding"] for p in planned["result"]["trajectory"]} == {"right"}
        assert carol.post(f"/v1/jobs/{recover}/approve", json={"plan_sha256": planned["plan_sha256"]}).status_code == 200
        assert bob.post(f"/v1/jobs/{recover}/dispatch").status_code == 202
        done = wait_state(bob, recover, END_STATES, timeout=60)
        assert done["state"] == "succeeded", (done["message"], done["error"])


def test_the_stop_is_sent_again_when_a_lost_controller_returns(tmp_path: Path) -> None:
    """SIGSTOP of the controller mid-execution: the job ends aborted (controller lost); after SIGCONT the
    dispatcher hears from it again and sends the stop again, and the job's audit records that after its end."""
    port = free_port()
    settings = {"bridge_lease_s": "6"}  # the link outlives the freeze: the watchdog, not the lease, sees it
    srv = Server(tmp_path, workers=1, bridge_port=port, **settings).start()
    proc = start_controller_sim(srv.data_dir, port, speed=1, **settings)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        job_id = submit_approved_plan(srv, {"scenario": "move-6"})
        with srv.client("bob") as bob:
            assert bob.post(f"/v1/jobs/{job_id}/dispatch").status_code == 202
            wait_state(bob, job_id, {"executing"} | END_STATES, timeout=30)
            time.sleep(1.0)
            proc.send_signal(signal.SIGSTOP)
            done = wait_state(bob, job_id, END_STATES, timeout=30)
            assert done["state"] == "aborted" and "controller lost" in done["error"]["message"], done["error"]
            proc.send_signal(signal.SIGCONT)
            deadline = time.monotonic() + 20
            while not any(e["kind"] == "bridge" and e["data"].get("event") == "stop_resent"
                          for e in job_events(bob, job_id)):
                assert time.monotonic() < deadline, "the stop was never re-sent"
                time.sleep(0.2)
        records = _audit_events(srv, job_id, want="stop_resent")
        kinds = [k for k, _ in records]
        assert kinds.index("stop_resent") > max(i for i, (k, p) in enumerate(records)
                                                if k == "state" and p["state"] == "aborted")
        resent = next(p for k, p in records if k == "stop_resent")["data"]
        assert resent["job_id"] == job_id and "controller lost" in resent["aborted_for"]
    finally:
        proc.send_signal(signal.SIGCONT)
        proc.kill()
        proc.wait(10)
        srv.stop()


def test_without_a_signing_key_the_service_plans_but_dispatch_answers_409(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=1)
    srv.env.pop("REGRASP_BRIDGE_SIGNING_KEY")
    srv.start()
    try:
        job_id = submit_approved_plan(srv, {"scenario": "stand-1"})
        with srv.client("bob") as bob:
            r = bob.post(f"/v1/jobs/{job_id}/dispatch")
            assert r.status_code == 409 and "no signing key" in r.json()["detail"], r.text
            assert bob.get(f"/v1/jobs/{job_id}").json()["state"] == "approved"
    finally:
        srv.stop()
