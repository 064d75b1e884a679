"""A survey on a real two-node Ray cluster on this machine, on loopback only.

The cluster (two nodes with node address 127.0.0.1, Ray's files in a temporary directory, token
auth) is started by a helper process of the test's own (ray_two_nodes.py) and stopped by it.
`regrasp survey --ray-address` runs its seeds as tasks on both nodes (the node id of every task is
printed) and gets the survey the local executor gets for the same seeds; `regrasp serve --executor
ray --ray-address` runs a survey job's seeds across the cluster, and cancelling the job cancels them.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator

import pytest
from conftest import ROOT, Server, free_port, wait_state

from planner.scene.scenarios import load_scenario
from planner.survey.estimator import Estimator
from planner.survey.runner import run_survey
from service.settings import DEFAULT_HANDLERS

try:
    import ray  # noqa: F401
except Exception as exc:  # noqa: BLE001 - any import failure means: no Ray here
    pytest.skip(f"ray cannot be imported ({exc})", allow_module_level=True)

HERE = Path(__file__).parent
DATA = HERE.parent / "data"
#: Two Ray nodes take tens of seconds to start on a loaded two-core machine.
CLUSTER_STARTUP_S = 180
#: CPUs each node offers (the service's actor takes one of the four).
CPUS_PER_NODE = 2


class TwoNodes:
    """The helper process that owns the cluster; its stdin closing stops both nodes."""

    def __init__(self, temp_dir: str) -> None:
        self.env = dict(os.environ, RAY_TMPDIR=temp_dir, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16),
                        # Ray 2.60 replaces a loopback address by the machine's network address unless told
                        # it runs on one machine: the drivers then reach the cluster on 127.0.0.1 too.
                        RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_USAGE_STATS_ENABLED="0",
                        PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        self.log = open(Path(temp_dir) / "cluster.log", "wb")
        self.proc = subprocess.Popen([sys.executable, str(HERE / "ray_two_nodes.py"), temp_dir, str(CPUS_PER_NODE)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log, env=self.env,
                                     text=True, start_new_session=True)
        line = self._line(CLUSTER_STARTUP_S)
        info = json.loads(line)
        self.address, self.nodes, self.ips = info["address"], set(info["nodes"]), info["ips"]

    def _line(self, timeout: float) -> str:
        import selectors

        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout):
            raise RuntimeError(f"the Ray cluster helper said nothing within {timeout} s")
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the Ray cluster helper ended: {self.proc.wait(5)}")
        return line

    def free_cpus(self) -> float:
        self.proc.stdin.write("cpus\n")
        self.proc.stdin.flush()
        return json.loads(self._line(30))["CPU"]

    def stop(self) -> None:
        try:
            self.proc.stdin.close()
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, 9)
            self.proc.wait(10)
        self.log.close()


@pytest.fixture(scope="module")
def cluster() -> Iterator[TwoNodes]:
    # A short directory: Ray's Unix socket paths live under it.
    with tempfile.TemporaryDirectory(prefix="rt", dir="/tmp") as temp_dir:
        nodes = TwoNodes(temp_dir)
        try:
            yield nodes
        finally:
            nodes.stop()


def test_the_cluster_is_two_nodes_on_loopback(cluster: TwoNodes) -> None:
    assert len(cluster.nodes) == 2 and cluster.ips == ["127.0.0.1"]
    assert cluster.address.startswith("127.0.0.1:")


def test_a_survey_runs_on_both_nodes_and_matches_the_local_executor(cluster: TwoNodes, tmp_path: Path) -> None:
    args = ["survey", str(DATA / "small-box.yaml"), "--states", "100", "--seeds-min", "3", "--seeds-max", "3"]
    env = dict(cluster.env, REGRASP_SURVEY_CACHE_DIR=str(tmp_path / "cache"))
    out = subprocess.run([sys.executable, "-m", "service.cli.main", *args, "--json", "--ray-address", cluster.address],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    on_ray = json.loads(out.stdout)
    placed = re.search(r"Ray: (\d+) seeds ran on (\d+) node\(s\): (.*)", out.stderr)
    assert placed, out.stderr[-2000:]
    per_node = dict(re.findall(r"([0-9a-f]{40,}) \((\d+)\)", placed.group(3)))
    assert set(per_node) == cluster.nodes  # every task's node is one of the cluster's, and both ran seeds
    assert sum(int(n) for n in per_node.values()) == int(placed.group(1)) == sum(r["seeds"] for r in on_ray["rows"]) > 0
    est = Estimator(until="states", states_per_seed=100, seeds_min=3, seeds_max=3)
    local, _ = run_survey(load_scenario(DATA / "small-box.yaml"), estimator=est, workers=1, keep_states=False)
    assert [r["hands"] for r in local["rows"]] == [r["hands"] for r in on_ray["rows"]]
    for a, b in zip(local["rows"], on_ray["rows"]):
        assert (a["per_seed"], a["ratio"], a["ratio_ci95"], a["reason"]) == (b["per_seed"], b["ratio"], b["ratio_ci95"],
                                                                            b["reason"])
    assert local["recommended"] == on_ray["recommended"]


def test_cancelling_a_survey_job_cancels_its_tasks_on_the_cluster(cluster: TwoNodes, tmp_path: Path) -> None:
    srv = Server(tmp_path / "srv", workers=1, extra_args=["--executor", "ray", "--ray-address", cluster.address],
                 startup_timeout_s=CLUSTER_STARTUP_S, handlers=DEFAULT_HANDLERS, audit="false", cancel_grace_s="5")
    srv.env.update({k: v for k, v in cluster.env.items() if k.startswith("RAY_")})
    srv.env["REGRASP_SURVEY_CACHE_DIR"] = str(tmp_path / "cache")
    try:
        srv.start()
        with srv.client("alice") as c:
            total = cluster.free_cpus()
            job = c.post("/v1/jobs", json={"kind": "survey", "request": {
                "scenario": "upright", "until": "states", "states_per_seed": 200_000, "seeds_min": 40,
                "seeds_max": 40}}).json()
            deadline = time.monotonic() + CLUSTER_STARTUP_S
            busy = total
            while time.monotonic() < deadline:  # the seeds' tasks hold the cluster's CPUs
                state = c.get(f"/v1/jobs/{job['id']}").json()
                assert state["state"] in ("queued", "planning"), state
                busy = cluster.free_cpus()
                if busy <= total - 3:
                    break
                time.sleep(0.5)
            assert busy <= total - 3, f"the survey's tasks never ran: {busy} of {total} CPUs free"
            assert c.post(f"/v1/jobs/{job['id']}/cancel").status_code in (200, 202)
            assert wait_state(c, job["id"], {"canceled", "failed", "succeeded"}, 30)["state"] == "canceled"
            deadline = time.monotonic() + 15
            while cluster.free_cpus() < total and time.monotonic() < deadline:
                time.sleep(0.3)
            assert cluster.free_cpus() == total  # the job actor's CPU only is taken again: no seed task is left
    finally:
        srv.stop()


def test_an_address_where_no_cluster_answers_is_refused_in_one_line() -> None:
    address = f"127.0.0.1:{free_port()}"
    for command in (["survey", str(DATA / "small-box.yaml"), "--states", "50"], ["paper", "--quick", "--out", "x"]):
        out = subprocess.run([sys.executable, "-m", "service.cli.main", *command, "--ray-address", address],
                             cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert out.returncode == 2, out.stderr[-2000:]
        assert f"cannot join the Ray cluster at {address}: nothing answers" in out.stderr
        assert "Traceback" not in out.stderr + out.stdout


def test_a_cancelled_session_frees_the_cluster_even_from_seeds_stuck_in_c_code(cluster: TwoNodes) -> None:
    """Seeds inside a long C call (a cold worker loading the robot model or compiling its kernels) do not see a soft
    cancel; a cancelled job's session force-cancels them, so the cluster has its CPUs back within seconds, not
    when the call returns (20 s here)."""
    out = subprocess.run([sys.executable, str(HERE / "ray_cancel_driver.py"), cluster.address], cwd=ROOT,
                         env=cluster.env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["busy"] <= got["before"] - 2, got  # both stuck seeds held a CPU
    assert got["after"] == got["before"] and got["freed_s"] < 10, got
