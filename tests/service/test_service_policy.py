"""The site's safety policy through the real service: a plan made below its floor is a comparison that is never
approved or dispatched, the gate at dispatch vetoes a plan below the floor of the policy the service runs with,
and every gate verdict in the audit names the policy by its SHA-256.

Real ``regrasp serve`` processes and ``regrasp controller-sim`` on private loopback endpoints; the plans come
from the ``stand-S`` test handler (the upright posture held still, planned at the request's threshold).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import (
    closed_audit_events,
    MCAP_MAGIC,
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

from schemas.policy import default_policy, load_policy

pytestmark = pytest.mark.host_pauses(limit_s=0.5)
AUDIT_TIMEOUT_S = 20.0


def _gate_verdicts(srv: Server, job_id: str) -> list[dict[str, Any]]:
    """The gate verdicts recorded in the job's closed audit files (bounded wait for the audit process)."""
    events = closed_audit_events(srv, job_id, {"gate_verdict", "gate"}, AUDIT_TIMEOUT_S)
    return [p["verdict"] if k == "gate_verdict" else p["data"] for k, p in events if k in ("gate_verdict", "gate")]


def test_a_plan_below_the_floor_is_a_comparison_never_approved_or_dispatched(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=1).start()
    try:
        with srv.client("alice") as alice, srv.client("bob") as bob:
            low = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "stand-1", "threshold_m": 0.0}})
            assert low.status_code == 202, low.text
            job_id = low.json()["id"]
            done = wait_state(alice, job_id, END_STATES | {"planned"}, timeout=60)
            assert done["state"] == "succeeded" and done["comparison"] is True, done
            assert done["result"]["threshold_m"] == 0.0 and done["plan_sha256"]  # the plan is the result
            assert "comparison" in done["message"] and "30.0 mm floor" in done["message"]
            for action, who in (("approve", bob), ("dispatch", bob)):
                r = who.post(f"/v1/jobs/{job_id}/{action}", json={} if action == "approve" else None)
                assert r.status_code == 409, (action, r.text)
                detail = r.json()["detail"]
                assert "is a comparison" in detail and "30.0 mm floor" in detail and "built-in safety policy" in detail
            assert bob.get(f"/v1/jobs/{job_id}").json()["state"] == "succeeded"
            # At the floor: an ordinary plan, approvable.
            at_floor = submit_approved_plan(srv, {"scenario": "stand-1", "threshold_m": 0.03})
            job = bob.get(f"/v1/jobs/{at_floor}").json()
            assert job["state"] == "approved" and job["comparison"] is False
    finally:
        srv.stop()


def test_the_gate_at_dispatch_vetoes_a_plan_below_the_services_floor_and_the_audit_names_the_policy(
        tmp_path: Path) -> None:
    """A plan approved under the built-in policy (30 mm floor) is dispatched by a service restarted with a
    stricter site policy (45 mm): the gate vetoes it, naming the policy, and sends nothing; a plan made for the
    new floor runs. Each gate verdict in the audit carries the SHA-256 of the policy that judged it."""
    port = free_port()
    policy_file = tmp_path / "site-policy.yaml"
    policy_file.write_text("schema: regrasp.policy/1\nmargin_floor_m: 0.045\n")
    site = load_policy(policy_file)
    data = tmp_path / "data"
    srv = Server(data, workers=1, bridge_port=port).start()
    proc = None
    try:
        old = submit_approved_plan(srv, {"scenario": "stand-1", "threshold_m": 0.035})
        srv.stop()
        srv = Server(data, workers=1, bridge_port=port, policy=str(policy_file)).start()
        proc = start_controller_sim(srv.data_dir, port, speed=1)
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        with srv.client("bob") as bob:
            assert bob.post(f"/v1/jobs/{old}/dispatch").status_code == 202
            done = wait_state(bob, old, END_STATES, timeout=30)
            assert done["state"] == "rejected" and done["error"]["code"] == "GATE_VETO", done
            message = done["error"]["message"]
            assert "[policy]" in message and "35.0 mm" in message and "45.0 mm floor" in message
            assert "site-policy.yaml" in message and site.sha256()[:12] in message
            history = [e for e in job_events(bob, old) if e["kind"] == "bridge"]
            assert not any(e["data"].get("event") == "segment" for e in history)  # nothing was sent
        verdicts = _gate_verdicts(srv, old)
        assert verdicts and {v["policy_sha256"] for v in verdicts} == {site.sha256()}
        assert site.sha256() != default_policy().sha256()

        new = submit_approved_plan(srv, {"scenario": "stand-1", "threshold_m": 0.045})
        with srv.client("bob") as bob:
            assert bob.post(f"/v1/jobs/{new}/dispatch").status_code == 202
            done = wait_state(bob, new, END_STATES, timeout=30)
            assert done["state"] == "succeeded", (done["message"], done["error"])
        verdicts = _gate_verdicts(srv, new)
        assert all(v["passed"] and v["policy_sha256"] == site.sha256() and v["threshold_m"] == 0.045 for v in verdicts)
    finally:
        if proc is not None:
            stop_process(proc)
        srv.stop()


def _strip_risk_cards(data_dir: Path, job_id: str) -> int:
    """Remove the job's stored risk cards (as a plan planned before dry runs existed has none); how many."""
    import sqlite3

    (db,) = [p for p in data_dir.glob("*.sqlite")]
    with sqlite3.connect(db) as conn:
        rows = conn.execute("SELECT id, data FROM job_events WHERE job_id = ?", (job_id,)).fetchall()
        stripped = 0
        for event_id, text in rows:
            data = json.loads(text) if text else {}
            if isinstance(data, dict) and "risk" in data:
                data.pop("risk")
                conn.execute("UPDATE job_events SET data = ? WHERE id = ?", (json.dumps(data), event_id))
                stripped += 1
    return stripped


def test_a_site_policy_requiring_the_physics_pass_dispatches_a_plan_whose_dry_run_stood(tmp_path: Path) -> None:
    """``require_physics_pass: true`` in a site policy file: the plan's dry run (the risk card's, bound to its hash)
    goes to the bridge's gate, which judges it and lets the plan run; a plan without a dry run, and one whose dry
    run misses the policy's CoP floor, are refused with the reason and nothing is sent."""
    port = free_port()
    policy_file = tmp_path / "site-policy.yaml"
    policy_file.write_text("schema: regrasp.policy/1\nrequire_physics_pass: true\n")
    data = tmp_path / "data"
    srv = Server(data, workers=1, bridge_port=port, policy=str(policy_file)).start()
    proc = start_controller_sim(srv.data_dir, port, speed=1)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        stood = submit_approved_plan(srv, {"scenario": "stand-1", "threshold_m": 0.03})
        bare = submit_approved_plan(srv, {"scenario": "stand-1", "threshold_m": 0.031})
        low = submit_approved_plan(srv, {"scenario": "stand-1", "threshold_m": 0.032})
        with srv.client("bob") as bob:
            card = bob.get(f"/v1/jobs/{stood}/risk").json()["planning"]
            assert card["physics"]["stood"] is True, card.get("physics")
            cop = card["physics"]["report"]["min_cop_margin_m"]
            assert bob.post(f"/v1/jobs/{stood}/dispatch").status_code == 202
            done = wait_state(bob, stood, END_STATES, timeout=30)
            assert done["state"] == "succeeded", (done["message"], done["error"])
            gate = [e["data"]["payload"] for e in job_events(bob, stood)
                    if e["kind"] == "bridge" and e["data"].get("event") == "gate"]
            # the bridge's gate was given the dry run and judged it (not skipped for want of a report)
            assert gate and gate[0]["passed"] and "physics_dry_run" not in gate[0]["skipped"], gate

        assert _strip_risk_cards(srv.data_dir, bare) >= 1
        with srv.client("bob") as bob:
            r = bob.post(f"/v1/jobs/{bare}/dispatch")
            assert r.status_code == 409 and "requires a physics dry run, and this plan has none" in r.json()["detail"]
            assert bob.get(f"/v1/jobs/{bare}").json()["state"] == "approved"

        # A stricter site policy: a CoP floor above what this plan's dry run kept.
        srv.stop()
        policy_file.write_text(f"schema: regrasp.policy/1\nrequire_physics_pass: true\nmin_cop_margin_m: {cop + 0.005}\n")
        srv = Server(data, workers=1, bridge_port=port, policy=str(policy_file)).start()
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        with srv.client("bob") as bob:
            r = bob.post(f"/v1/jobs/{low}/dispatch")
            assert r.status_code == 409, r.text
            assert "below the safety policy's min_cop_margin_m" in r.json()["detail"], r.text
            history = [e for e in job_events(bob, low) if e["kind"] == "bridge"]
            assert not any(e["data"].get("event") == "segment" for e in history)  # nothing was sent
    finally:
        stop_process(proc)
        srv.stop()
