"""Audit heads that stay true: after a controller freeze and resume (a stop re-sent after the job ended,
recorded in a continuation file) and a kill -9 of the server with jobs in flight, every job's audit
download verifies against its stored head (`regrasp audit verify FILE --head <X-Audit-Head>`)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import (
    CONTROLLER_UP_TIMEOUT_S,
    END_STATES,
    ROOT,
    Server,
    free_port,
    job_events,
    start_controller_sim,
    stop_process,
    submit_approved_plan,
    wait_controller_alive,
    wait_state,
)

pytestmark = pytest.mark.host_pauses(limit_s=0.5)
#: The audit process writes a moment after the events (more on a loaded machine).
AUDIT_TIMEOUT_S = 30.0


def _verify_stored_head(srv: Server, job_id: str, out: Path) -> tuple[int, str]:
    """Download the job's audit file and verify it against the head the service stored for it: exit 0
    (intact) for a job that ended; a job still open (planned) may be unfinished (2), its chain intact up to
    the stored head. A head that does not agree is exit 1."""
    deadline = time.monotonic() + AUDIT_TIMEOUT_S
    with srv.client("alice") as c:
        while True:
            job = c.get(f"/v1/jobs/{job_id}").json()
            r = c.get(f"/v1/jobs/{job_id}/audit")
            head = r.headers.get("X-Audit-Head", "")
            settled = job["state"] in END_STATES | {"planned"} and r.status_code == 200 and head
            if settled:
                out.write_bytes(r.content)
                done = subprocess.run([sys.executable, "-m", "service.cli.main", "audit", "verify", str(out),
                                       "--head", head], cwd=ROOT, capture_output=True, text=True, timeout=120)
                ok = done.returncode == 0 or (done.returncode == 2 and job["state"] == "planned")
                if ok or time.monotonic() > deadline:
                    return 0 if ok else done.returncode, done.stdout + done.stderr
            assert time.monotonic() < deadline, f"job {job_id} never settled: {job['state']}, audit {r.status_code}"
            time.sleep(0.5)


def test_every_job_verifies_against_its_stored_head_after_freeze_resume_and_kill_9(tmp_path: Path) -> None:
    port = free_port()
    settings = {"bridge_lease_s": "6"}  # the link outlives the freeze: the watchdog, not the lease, sees it
    data = tmp_path / "data"
    srv = Server(data, workers=1, bridge_port=port, **settings)
    proc = None
    jobs: list[str] = []
    try:
        srv.start()
        proc = start_controller_sim(srv.data_dir, port, speed=1, **settings)
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        frozen = submit_approved_plan(srv, {"scenario": "move-6"})
        jobs.append(frozen)
        with srv.client("bob") as bob:
            assert bob.post(f"/v1/jobs/{frozen}/dispatch").status_code == 202
            wait_state(bob, frozen, {"executing"} | END_STATES, timeout=30)
            time.sleep(1.0)
            proc.send_signal(signal.SIGSTOP)
            assert wait_state(bob, frozen, END_STATES, timeout=30)["state"] == "aborted"
            proc.send_signal(signal.SIGCONT)
            deadline = time.monotonic() + 20
            while not any(e["kind"] == "bridge" and e["data"].get("event") == "stop_resent"
                          for e in job_events(bob, frozen)):
                assert time.monotonic() < deadline, "the stop was never re-sent"
                time.sleep(0.2)
        code, text = _verify_stored_head(srv, frozen, tmp_path / "frozen.mcap")
        assert code == 0, text
        # Jobs in flight when the server is killed: one planning, one planned.
        with srv.client("alice") as alice:
            busy = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-4"}}).json()["id"]
            wait_state(alice, busy, {"planning"}, 30)
        planned = submit_approved_plan(srv, {"scenario": "stand-1"})
        jobs += [busy, planned]
        time.sleep(1.0)  # the audit pump has written their records so far
        srv.kill()
        srv = Server(data, workers=1, bridge_port=port, **settings)
        srv.start()
        with srv.client("bob") as bob:
            assert bob.post(f"/v1/jobs/{planned}/dispatch").status_code == 202
            wait_state(bob, planned, END_STATES, timeout=60)
            wait_state(bob, busy, END_STATES | {"planned"}, timeout=60)  # planned again after the restart
        continued = sorted(p.name for p in (data / "audit").glob("*.*.mcap"))
        assert continued, "no job was continued in a new audit file"
        for job_id in jobs:
            code, text = _verify_stored_head(srv, job_id, tmp_path / f"{job_id}.mcap")
            assert code == 0, f"job {job_id}: {text}"
    finally:
        if proc is not None:
            proc.send_signal(signal.SIGCONT)
            stop_process(proc)
        srv.stop()
