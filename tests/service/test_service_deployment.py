"""Deployment paths run as real processes: `regrasp serve --dev`, and an API replica with a separate
`regrasp worker` on one job store (whose workers' durations and outcomes the API's /metrics reports,
and whose worker processes each load the robot model once)."""

from __future__ import annotations

import json
import os
import re
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import httpx
import psutil
import pytest
from conftest import ROOT, Server, free_port, service_env, stop_process, wait_state
from prometheus_client.parser import text_string_to_metric_families

from schemas.jobs import TERMINAL_STATES

# ------------------------------------------------------------------ --dev


@pytest.mark.parametrize("host", ["0.0.0.0", "example.org"])
def test_dev_refuses_a_non_loopback_address(tmp_path: Path, host: str) -> None:
    port = free_port()
    env = service_env()
    env.pop("REGRASP_TOKENS")
    proc = subprocess.run([sys.executable, "-m", "service.cli.main", "serve", "--dev", "--host", host, "--port",
                           str(port), "--data-dir", str(tmp_path), "--workers", "0"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert f"only allowed on a loopback address, not {host!r}" in proc.stderr
    assert not (tmp_path / "dev-tokens.json").exists()  # no token was made
    assert "dev-" not in proc.stdout


def test_dev_prints_working_demo_tokens_and_keeps_them_in_a_0600_file(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=0, extra_args=["--dev"], audit="false")
    del srv.env["REGRASP_TOKENS"]  # only the demo tokens exist
    srv.start()
    try:
        printed = dict(re.findall(r"^\s+(alice|bob|carol|admin)\s+\S+\s+(dev-\S+)\s*$", srv.log_path.read_text(), re.M))
        assert set(printed) == {"alice", "bob", "carol", "admin"}, srv.log_path.read_text()
        token_file = tmp_path / "dev-tokens.json"
        assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
        saved = json.loads(token_file.read_text())
        assert {user: entry["token"] for user, entry in saved.items()} == printed
        assert saved["bob"]["roles"] == ["approver", "operator"]

        def call(user: str | None, method: str, path: str, **kw: object) -> httpx.Response:
            headers = {"Authorization": f"Bearer {printed[user]}"} if user else {"Authorization": "Bearer dev-nobody-x"}
            return httpx.request(method, srv.url + path, headers=headers, timeout=30, **kw)  # type: ignore[arg-type]

        job = call("alice", "POST", "/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}})
        assert job.status_code == 202, job.text
        assert call("carol", "GET", f"/v1/jobs/{job.json()['id']}").status_code == 200
        assert call("carol", "POST", "/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}}).status_code == 403
        assert call(None, "GET", "/v1/jobs").status_code == 401
    finally:
        srv.stop()


# ------------------------------------------------------- split deployment
def _parse(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    out = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            out[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return out


class Split:
    """An API replica with no workers and a `regrasp worker` process, sharing one SQLite store."""

    def __init__(self, data_dir: Path) -> None:
        self.api = Server(data_dir, workers=0, audit="false")
        self.worker_log = open(data_dir / "worker.log", "ab")
        self.worker = subprocess.Popen(
            [sys.executable, "-m", "service.cli.main", "worker", "--workers", "2", "--data-dir", str(data_dir),
             "--log-level", "warning"],
            cwd=ROOT, env=service_env(preload_robot="true"), stdout=self.worker_log, stderr=subprocess.STDOUT,
            start_new_session=True)

    def wait_until_claiming(self, timeout_s: float = 120.0) -> None:
        """Until the worker says it runs (its start line); a worker that exited fails here with its log."""
        log_path = Path(self.worker_log.name)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if re.search(r"^worker \S+: 2 local worker", log_path.read_text(errors="replace"), re.M):
                return
            if self.worker.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"the worker did not start (exit {self.worker.poll()}): {log_path.read_text()[-3000:]}")

    def stop(self) -> None:
        stop_process(self.worker, timeout=20)
        try:
            os.killpg(self.worker.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.worker_log.close()
        self.api.stop()


@pytest.fixture(scope="module")
def split(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Split]:
    deployment = Split(tmp_path_factory.mktemp("split"))
    try:
        deployment.api.start()
        deployment.wait_until_claiming()
        yield deployment
    finally:
        deployment.stop()


def test_api_metrics_report_the_separate_workers_durations_and_outcomes(split: Split) -> None:
    with split.api.client("alice") as c:
        assert c.get("/healthz").json()["workers"] == 0  # this process plans nothing
        jobs = {name: c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": name}}).json()["id"]
                for name in ("busy-5.5", "quick", "error")}
        survey = c.post("/v1/jobs", json={"kind": "survey", "request": {"scenario": "quick"}}).json()["id"]
        finals = {j: wait_state(c, j, TERMINAL_STATES | {"planned"}, timeout=120) for j in [*jobs.values(), survey]}
        slow = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-30"}}).json()["id"]
        wait_state(c, slow, {"planning"}, timeout=60)
        c.post(f"/v1/jobs/{slow}/cancel")
        finals[slow] = wait_state(c, slow, TERMINAL_STATES, timeout=10)
        assert [finals[jobs[n]]["state"] for n in ("busy-5.5", "quick", "error")] == ["planned", "planned", "failed"]
        assert finals[survey]["state"] == "succeeded" and finals[slow]["state"] == "canceled"
        metrics = _parse(c.get("/metrics").text)

    def value(name: str, kind: str, outcome: str, **labels: str) -> float:
        key = tuple(sorted({"kind": kind, "outcome": outcome, **labels}.items()))
        return metrics.get((name, key), 0.0)

    assert value("regrasp_job_outcomes_total", "plan", "planned") == 2
    assert value("regrasp_job_outcomes_total", "plan", "failed") == 1
    assert value("regrasp_job_outcomes_total", "plan", "canceled") == 1
    assert value("regrasp_job_outcomes_total", "survey", "succeeded") == 1
    assert value("regrasp_job_duration_seconds_count", "plan", "planned") == 2
    # busy-5.5 planned for at least 5.5 s, quick for far less (under a second on a quiet machine, over one on a busy
    # CI run): one each side of the 5 s bucket
    assert value("regrasp_job_duration_seconds_bucket", "plan", "planned", le="5.0") == 1
    assert value("regrasp_job_duration_seconds_bucket", "plan", "planned", le="+Inf") == 2
    assert value("regrasp_job_duration_seconds_sum", "plan", "planned") >= 5.5
    assert value("regrasp_job_duration_seconds_count", "plan", "canceled") == 1


def test_each_worker_process_loads_the_robot_once(split: Split) -> None:
    with split.api.client("alice") as c:
        ids = [c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "robot", "seed": i}}).json()["id"]
               for i in range(8)]
        results = [wait_state(c, j, {"planned", "failed"}, timeout=120)["result"] for j in ids]
    workers = {p.pid for p in psutil.Process(split.worker.pid).children(recursive=True)}
    by_pid: dict[int, list[dict]] = {}
    for r in results:
        by_pid.setdefault(r["pid"], []).append(r)
    assert set(by_pid) <= workers and split.api.proc.pid not in by_pid  # planned in the worker's processes
    for pid, runs in by_pid.items():
        # loaded before the first job (the handler's own load is a cache hit) and never again, however many jobs
        assert all(r["robot_loads"] == 1 for r in runs), (pid, runs)
        assert min(r["robot_cache_hits"] for r in runs) >= 1
        assert len({r["robot_cache_hits"] for r in runs}) == len(runs)  # one process, one cache, across its jobs
