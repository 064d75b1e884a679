"""End to end against a real `regrasp serve` on 127.0.0.1: submit, progress, cancel, approve, errors."""

from __future__ import annotations

import json
import time

import httpx
import pytest
from conftest import TOKEN, Server, cancel_latency_s, wait_state

from schemas.plan import plan_sha256
from service.client import ServiceClient, ServiceError, parse_sse
from service.jobs.worker_process import INTERNAL_ERROR_MESSAGE


def submit(c: httpx.Client, scenario: str, kind: str = "plan", **request: object) -> dict:
    r = c.post("/v1/jobs", json={"kind": kind, "request": {"scenario": scenario, **request}})
    assert r.status_code == 202, r.text
    assert r.headers["location"] == f"/v1/jobs/{r.json()['id']}"
    return r.json()


def events_until(server: Server, user: str, job_id: str, stop_states: set[str], timeout: float = 20.0) -> list[dict]:
    out = []
    with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {TOKEN[user]}"}) as c:
        with c.stream("GET", f"/v1/jobs/{job_id}/events", timeout=timeout) as resp:
            assert resp.status_code == 200
            assert resp.headers["content-type"].startswith("text/event-stream")
            for ev in parse_sse(resp.iter_lines()):
                out.append(ev)
                if ev["kind"] == "state" and ev["state"] in stop_states:
                    break
    return out


def test_auth_errors_are_problems(server: Server, alice: httpx.Client, bob: httpx.Client) -> None:
    r = httpx.get(server.url + "/v1/jobs")
    assert r.status_code == 401 and r.headers["content-type"] == "application/problem+json"
    assert r.headers["www-authenticate"].startswith("Bearer")
    assert "bearer token" in r.json()["detail"]
    r = httpx.get(server.url + "/v1/jobs", headers={"Authorization": "Bearer nope-nope-nope"})
    assert r.status_code == 401 and r.json()["detail"] == "unknown bearer token"
    r = bob.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}})
    assert r.status_code == 403 and "planner" in r.json()["detail"]
    assert bob.get("/v1/jobs").status_code == 200  # any authenticated user reads


def test_submit_progress_result_and_provenance(server: Server, alice: httpx.Client) -> None:
    job = submit(alice, "busy-1.5", seed=7)
    assert job["state"] == "queued" and job["submitter"] == "alice"
    events = events_until(server, "alice", job["id"], {"planned", "failed"})
    states = [e["state"] for e in events if e["kind"] == "state"]
    assert states == ["queued", "planning", "planned"]
    progress = [e["progress"] for e in events if e["kind"] == "progress"]
    assert len(progress) >= 2 and progress == sorted(progress) and 0 < progress[-1] <= 1
    done = alice.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "planned" and done["progress"] == 1.0
    assert done["result"]["iterations"] > 0 and done["plan_sha256"] == plan_sha256(done["result"])
    prov = done["provenance"]
    assert prov["seed"] == 7 and prov["robot"] == "hrp5p" and len(prov["robot_sha256"]) == 64
    assert prov["code_version"] and "numpy" in prov["library_versions"]


@pytest.mark.host_pauses(limit_s=0.2)
def test_cancel_while_planning_stops_within_1s(alice: httpx.Client) -> None:
    job = submit(alice, "busy-30")
    wait_state(alice, job["id"], {"planning"})
    time.sleep(0.3)
    t0 = time.monotonic()
    r = alice.post(f"/v1/jobs/{job['id']}/cancel", json={"reason": "test"})
    assert r.status_code == 202 and r.json()["cancel_requested"]
    done = wait_state(alice, job["id"], {"canceled", "planned", "failed"}, timeout=5)
    assert done["state"] == "canceled" and done["message"] == "stopped after a cancel"
    assert cancel_latency_s(alice, job["id"]) < 1.0  # server clock: the stored request to the stored end
    assert time.monotonic() - t0 < 3.0  # and the client saw it soon after (polling and a loaded machine included)


@pytest.mark.host_pauses(limit_s=0.2)
def test_cancel_of_a_handler_that_never_polls_kills_it_within_1s(alice: httpx.Client) -> None:
    job = submit(alice, "hang-30")
    wait_state(alice, job["id"], {"planning"})
    time.sleep(0.3)
    t0 = time.monotonic()
    alice.post(f"/v1/jobs/{job['id']}/cancel")
    done = wait_state(alice, job["id"], {"canceled", "planned", "failed"}, timeout=5)
    assert done["state"] == "canceled" and "worker killed" in done["message"]
    assert cancel_latency_s(alice, job["id"]) < 1.0  # server clock: the stored request to the stored end
    assert time.monotonic() - t0 < 3.0


def test_cancel_before_start_never_runs(alice: httpx.Client) -> None:
    blockers = [submit(alice, "busy-3") for _ in range(2)]
    waiting = submit(alice, "busy-1")
    r = alice.post(f"/v1/jobs/{waiting['id']}/cancel")
    assert r.status_code == 202 and r.json()["state"] == "canceled"
    for b in blockers:
        alice.post(f"/v1/jobs/{b['id']}/cancel")
    events = alice.get(f"/v1/jobs/{waiting['id']}").json()
    assert events["started_at"] is None and events["attempts"] == 0


def test_cancel_rules(server: Server, alice: httpx.Client, bob: httpx.Client) -> None:
    job = submit(alice, "quick")
    r = bob.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code == 403 and "submitter" in r.json()["detail"]
    wait_state(alice, job["id"], {"planned"})
    with server.client("admin") as admin:
        assert admin.post(f"/v1/jobs/{job['id']}/cancel").json()["state"] == "canceled"
    r = alice.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code == 409 and "canceled" in r.json()["detail"]


def test_failures_timeout_crash_error_infeasible(alice: httpx.Client) -> None:
    jobs = {name: submit(alice, name, **extra) for name, extra in
            [("error", {}), ("infeasible", {}), ("crash", {}), ("busy-30", {"time_limit_s": 1.0})]}
    done = {name: wait_state(alice, j["id"], {"failed", "planned", "canceled"}, timeout=15) for name, j in jobs.items()}
    assert all(d["state"] == "failed" for d in done.values()), {k: v["state"] for k, v in done.items()}
    # An unexpected exception's text and class stay in the log: every user reads a job's error.
    assert done["error"]["error"] == {"code": "ERROR", "message": INTERNAL_ERROR_MESSAGE}
    assert done["infeasible"]["error"]["code"] == "COM_MARGIN" and done["infeasible"]["result"]["status"] == "infeasible"
    assert done["crash"]["error"]["code"] == "WORKER_CRASHED" and "SIGKILL" in done["crash"]["error"]["message"]
    assert done["busy-30"]["error"]["code"] == "TIMEOUT"
    # the pool recovered: a new job still runs
    assert wait_state(alice, submit(alice, "quick")["id"], {"planned"})["state"] == "planned"


def test_approval_two_person_rule_hash_binding_and_expiry(server: Server, alice: httpx.Client, bob: httpx.Client) -> None:
    with server.client("dave") as dave, server.client("carol") as carol:
        job = submit(dave, "busy-0.3")
        planned = wait_state(dave, job["id"], {"planned"})
        sha = planned["plan_sha256"]
        r = dave.post(f"/v1/jobs/{job['id']}/approve")
        assert r.status_code == 403 and "two-person rule" in r.json()["detail"]
        r = alice.post(f"/v1/jobs/{job['id']}/approve")
        assert r.status_code == 403 and "approver" in r.json()["detail"]
        r = bob.post(f"/v1/jobs/{job['id']}/approve", json={"plan_sha256": "0" * 64})
        assert r.status_code == 409 and sha in r.json()["detail"]
        r = bob.post(f"/v1/jobs/{job['id']}/dispatch")
        assert r.status_code == 409 and "not approved" in r.json()["detail"]
        r = bob.post(f"/v1/jobs/{job['id']}/approve", json={"plan_sha256": sha, "comment": "looks fine"})
        assert r.status_code == 200, r.text
        approved = r.json()
        assert approved["state"] == "approved" and approved["approval"]["approved_by"] == "bob"
        assert approved["approval"]["plan_sha256"] == sha == plan_sha256(approved["result"])
        assert alice.post(f"/v1/jobs/{job['id']}/dispatch").status_code == 403
        r = bob.post(f"/v1/jobs/{job['id']}/dispatch")
        assert r.status_code == 409 and "no controller is alive" in r.json()["detail"]
        time.sleep(3.3)  # the test server's approval TTL is 3 s
        expired = dave.get(f"/v1/jobs/{job['id']}").json()
        assert expired["state"] == "planned" and expired["approval"] is None
        for body in (None, {}, {"reason": ""}, {"reason": "   "}):  # a rejection says why
            r = carol.post(f"/v1/jobs/{job['id']}/reject", json=body)
            assert r.status_code == 422 and "reason" in r.json()["detail"], (body, r.text)
            assert "errors.pydantic.dev" not in r.text
        assert dave.get(f"/v1/jobs/{job['id']}").json()["state"] == "planned"
        r = carol.post(f"/v1/jobs/{job['id']}/reject", json={"reason": "not today"})
        assert r.status_code == 200 and r.json()["state"] == "rejected"
        assert "not today" in r.json()["error"]["message"]
        states = [e["state"] for e in events_until(server, "carol", job["id"], {"rejected"}) if e["kind"] == "state"]
        assert states == ["queued", "planning", "planned", "approved", "planned", "rejected"]


def test_idempotent_resubmit(alice: httpx.Client) -> None:
    body = {"kind": "survey", "request": {"scenario": "quick", "seed": 3}}
    a = alice.post("/v1/jobs", json=body, headers={"Idempotency-Key": "k-123"})
    b = alice.post("/v1/jobs", json=body, headers={"Idempotency-Key": "k-123"})
    assert a.status_code == b.status_code == 202
    assert a.json()["id"] == b.json()["id"] and b.headers["idempotent-replayed"] == "true"
    assert a.headers["location"] == b.headers["location"]
    c = alice.post("/v1/jobs", json={**body, "request": {"scenario": "quick", "seed": 4}}, headers={"Idempotency-Key": "k-123"})
    assert c.status_code == 409 and "different request" in c.json()["detail"]
    d = alice.post("/v1/jobs", json=body, headers={"Idempotency-Key": "k-124"})
    assert d.json()["id"] != a.json()["id"]


def test_validation_size_and_not_found_problems(server: Server, alice: httpx.Client) -> None:
    r = alice.post("/v1/jobs", json={"kind": "dance", "request": {}})
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"
    assert "body kind" in r.json()["detail"] and "body request.scenario" in r.json()["detail"]
    r = alice.post("/v1/jobs", content='{"kind": "plan", "request": {"scenario": "x", "threshold_m": NaN}}',
                   headers={"content-type": "application/json"})
    assert r.status_code == 422 and "threshold_m" in r.json()["detail"]
    r = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": {"name": "bad"}}})
    assert r.status_code == 422 and "inline scenario" in r.json()["detail"]
    r = alice.post("/v1/jobs", content=b"{" + b" " * 300_000 + b"}", headers={"content-type": "application/json"})
    assert r.status_code == 413 and "over the limit" in r.json()["detail"]
    r = alice.get("/v1/jobs/does-not-exist")
    assert r.status_code == 404 and "does-not-exist" in r.json()["detail"]
    assert alice.get("/nowhere").json()["status"] == 404


def test_list_health_metrics_console_audit(server: Server, alice: httpx.Client) -> None:
    job = wait_state(alice, submit(alice, "quick", kind="survey")["id"], {"succeeded"})
    listing = alice.get("/v1/jobs", params={"kind": "survey", "state": "succeeded", "limit": 5}).json()
    assert listing["total"] >= 1 and all(j["kind"] == "survey" for j in listing["jobs"])
    assert listing["jobs"][0]["result"] is None
    health = httpx.get(server.url + "/healthz").json()
    assert health["status"] == "ok" and health["workers"] == 2 and health["database"] == "sqlite"
    assert httpx.get(server.url + "/metrics").status_code == 401  # behind a token
    doc = httpx.get(server.url + "/openapi.json").json()  # ... and the OpenAPI document says so
    schemes = doc["components"]["securitySchemes"]
    assert [next(iter(s)) for s in doc["paths"]["/metrics"]["get"]["security"]] == ["HTTPBearer"]
    assert schemes["HTTPBearer"]["scheme"] == "bearer"
    assert doc["paths"]["/v1/jobs/{job_id}/reject"]["post"]["requestBody"]["required"] is True
    metrics = alice.get("/metrics").text
    assert "regrasp_queue_depth" in metrics and "regrasp_job_duration_seconds_bucket" in metrics
    assert 'regrasp_jobs{kind="survey",state="succeeded"}' in metrics
    root = httpx.get(server.url + "/")
    assert root.status_code == 200 and "html" in root.headers["content-type"]
    time.sleep(0.5)  # the audit pump runs every 0.2 s
    r = alice.get(f"/v1/jobs/{job['id']}/audit")
    assert r.status_code == 200 and r.content[:8] == b"\x89MCAP0\r\n"
    head = alice.get(f"/v1/jobs/{job['id']}").json()["audit_head"]
    assert head and r.headers["x-audit-head"] == head


def test_client_wait_replays_the_events_of_a_job_that_already_settled(server: Server) -> None:
    """A fast job can settle before the caller starts waiting: on_event still sees its history."""
    with ServiceClient(server.url, TOKEN["alice"]) as alice:
        job = alice.submit("plan", {"scenario": "busy-0.1"})
        assert alice.wait(job["id"], timeout=20)["state"] == "planned"
        seen: list[dict] = []
        done = alice.wait(job["id"], on_event=seen.append, timeout=20)
        assert done["state"] == "planned"
        assert any(e["kind"] == "progress" for e in seen)
        assert seen[-1]["kind"] == "state" and seen[-1]["state"] == "planned"


def test_python_client(server: Server) -> None:
    with ServiceClient(server.url, TOKEN["alice"]) as alice, ServiceClient(server.url, TOKEN["bob"]) as bob:
        job = alice.submit("plan", {"scenario": "busy-0.5"}, idempotency_key="client-1")
        seen: list[dict] = []
        done = alice.wait(job["id"], on_event=seen.append, timeout=20)
        assert done["state"] == "planned" and any(e["kind"] == "progress" for e in seen)
        assert bob.approve(job["id"], plan_sha256=done["plan_sha256"])["state"] == "approved"
        with pytest.raises(ServiceError) as err:
            bob.dispatch(job["id"])
        assert err.value.status == 409 and "controller" in err.value.problem["detail"]
        assert json.dumps(alice.health())
