"""Concurrency, backpressure and crash safety against real server processes."""

from __future__ import annotations

import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import psutil
from conftest import TOKEN, Server, wait_state

from schemas.jobs import TERMINAL_STATES


def test_200_submissions_from_20_clients_all_accounted_for(server: Server) -> None:
    def client_run(i: int) -> list[str]:
        ids = []
        with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {TOKEN['alice']}"}, timeout=30) as c:
            for k in range(10):
                r = c.post("/v1/jobs", json={"kind": "survey", "request": {"scenario": "quick", "seed": i * 100 + k}},
                           headers={"Idempotency-Key": f"load-{i}-{k}"})
                assert r.status_code == 202, r.text
                ids.append(r.json()["id"])
        return ids

    with ThreadPoolExecutor(20) as pool:
        ids = [j for chunk in pool.map(client_run, range(20)) for j in chunk]
    assert len(ids) == 200 and len(set(ids)) == 200
    with server.client("admin") as admin:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            listing = admin.get("/v1/jobs", params={"limit": 500, "submitter": "alice", "kind": "survey"}).json()
            mine = {j["id"]: j for j in listing["jobs"] if j["id"] in set(ids)}
            if len(mine) == 200 and all(j["state"] == "succeeded" for j in mine.values()):
                break
            time.sleep(0.3)
        assert len(mine) == 200
        assert {j["state"] for j in mine.values()} == {"succeeded"}
        assert all(j["attempts"] == 1 for j in mine.values())  # each ran exactly once


def test_backpressure_429_with_retry_after(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=1, queue_limit="3", retry_after_s="7").start()
    try:
        with srv.client("alice") as c:
            codes = []
            for _ in range(6):
                r = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-20"}})
                codes.append(r.status_code)
                if r.status_code == 429:
                    assert r.headers["retry-after"] == "7"
                    assert r.headers["content-type"] == "application/problem+json"
                    assert "limit of 3" in r.json()["detail"]
            assert codes.count(202) in (3, 4) and codes[-1] == 429
    finally:
        srv.stop()


def _worker_pid(c: httpx.Client, job_id: str) -> int:
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        with c.stream("GET", f"/v1/jobs/{job_id}/events", timeout=5.0) as resp:
            for line in resp.iter_lines():
                if "running on local worker pid" in line:
                    return int(line.split("running on local worker pid ")[1].split('"')[0])
                if '"kind":"progress"' in line:
                    break
        time.sleep(0.1)
    raise AssertionError("no worker pid reported")


def test_kill_9_of_a_worker_fails_its_job_with_the_reason(server: Server, alice: httpx.Client) -> None:
    job = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-30"}}).json()
    pid = _worker_pid(alice, job["id"])
    os.kill(pid, signal.SIGKILL)
    done = wait_state(alice, job["id"], TERMINAL_STATES | {"planned"}, timeout=10)
    assert done["state"] == "failed" and done["error"]["code"] == "WORKER_CRASHED"
    assert str(pid) in done["error"]["message"] and "SIGKILL" in done["error"]["message"]
    again = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}}).json()
    assert wait_state(alice, again["id"], {"planned"})["state"] == "planned"


def test_kill_9_of_the_server_mid_job_loses_nothing(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=1, max_attempts="2").start()
    try:
        with srv.client("alice") as c:
            ids = [c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": f"busy-{s}"}}).json()["id"]
                   for s in (4, 0.5, 0.5)]
            wait_state(c, ids[0], {"planning"})
            time.sleep(0.5)
            deadline = time.monotonic() + 30  # let the audit process open the job's file before the crash
            while time.monotonic() < deadline and not c.get(f"/v1/jobs/{ids[0]}").json()["audit_head"]:
                time.sleep(0.1)
            workers = [p.pid for p in psutil.Process(srv.proc.pid).children(recursive=True)]
        srv.kill()
        time.sleep(1.0)  # orphaned workers notice their parent died within 0.2 s
        assert not [p for p in workers if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
        srv2 = Server(tmp_path, workers=1, port=srv.port, max_attempts="2").start()
        try:
            with srv2.client("alice") as c:
                final = {j: wait_state(c, j, {"planned", "failed"}, timeout=30) for j in ids}
                assert {f["state"] for f in final.values()} == {"planned"}
                assert final[ids[0]]["attempts"] == 2  # interrupted once, re-queued, finished
                assert final[ids[1]]["attempts"] == final[ids[2]]["attempts"] == 1
                listing = c.get("/v1/jobs", params={"limit": 50}).json()
                assert listing["total"] == 3  # no duplicate
                text = c.get(f"/v1/jobs/{ids[0]}/events", params={"follow": "false"}).text
                assert "re-queued" in text and text.count('"state":"planned"') == 1
                _check_audit_continuation(c, ids[0], tmp_path)
        finally:
            srv2.stop()
    finally:
        srv.stop()


def _check_audit_continuation(c: httpx.Client, job_id: str, data_dir: Path) -> None:
    """The killed server's audit file reads up to its last record; the job continues in a second file."""
    from service.audit import verify

    deadline = time.monotonic() + 30  # the audit process starts (spawn) and catches up
    job = c.get(f"/v1/jobs/{job_id}").json()
    files = sorted((data_dir / "audit").glob(f"{job_id}*.mcap"))
    while time.monotonic() < deadline and len(files) < 2:
        time.sleep(0.2)
        files = sorted((data_dir / "audit").glob(f"{job_id}*.mcap"))
    assert [f.name for f in files] == [f"{job_id}.1.mcap", f"{job_id}.mcap"]
    first = verify(data_dir / "audit" / f"{job_id}.mcap")
    assert first.status == "unfinished" and first.exit_code == 2, first.detail
    second = verify(data_dir / "audit" / f"{job_id}.1.mcap")
    assert second.status in ("unfinished", "intact"), second.detail  # still open: the job awaits approval
    assert job["audit_head"]
