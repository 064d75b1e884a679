"""Each fault of the physics plant (fall, foot tilt, torque saturation) aborts a real execution through the
service: a real ``regrasp serve`` with its zenoh bridge, ``regrasp controller-sim --plant physics`` with the fault
injected from the job's playback, the job ends ``aborted`` with the controller's reason, and the job's audit file
holds that reason and the balance stream (``/robot/balance``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import httpx
import pytest
from mcap.reader import make_reader

from tests.service.conftest import (
    BRIDGE_LEASE_S,
    BRIDGE_ROBOT_ID,
    BRIDGE_WATCHDOG_S,
    END_STATES,
    ROOT,
    Server,
    bridge_keys,
    free_port,
    stop_process,
    submit_approved_plan,
    wait_balance_stream,
    wait_controller_alive,
    wait_state,
)

pytestmark = pytest.mark.host_pauses(limit_s=0.5)
CONTROLLER_UP_TIMEOUT_S = 60.0
JOB_TIMEOUT_S = 90.0
AUDIT_CLOSED_TIMEOUT_S = 30.0
MCAP_MAGIC = b"\x89MCAP0\r\n"

#: How each fault is injected into the twin, and the words the job's reason must hold.
FAULTS = {
    "fall": (["--push-n", "800", "--push-s", "0.8", "--foot-tilt-limit-rad", "1.5", "--foot-lift-limit-mm", "1000"],
             "fall: base tilted"),
    "foot_tilt": (["--push-n", "300", "--push-s", "0.5"], "foot_tilt: a supporting sole tilted"),
    "torque_saturation": (["--effort-scale", "0.1"], "torque_saturation: "),
}


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, int]]:
    port = free_port()
    srv = Server(tmp_path_factory.mktemp("physics-faults"), workers=1, bridge_port=port).start()
    try:
        yield srv, port
    finally:
        srv.stop()


def _physics_controller(data_dir: Path, port: int, flags: list[str]) -> subprocess.Popen[bytes]:
    env = dict(os.environ, REGRASP_BRIDGE_LEASE_S=str(BRIDGE_LEASE_S),
               REGRASP_BRIDGE_WATCHDOG_TIMEOUT_S=str(BRIDGE_WATCHDOG_S),
               REGRASP_BRIDGE_TRUSTED_KEY=bridge_keys()["public"])
    log = open(data_dir / "controller-sim.log", "ab")
    return subprocess.Popen([sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", BRIDGE_ROBOT_ID,
                             "--listen", f"tcp/127.0.0.1:{port}", "--speed", "1", "--plant", "physics", *flags],
                            cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)


def _audit_messages(client: httpx.Client, job_id: str) -> list[tuple[str, dict]]:
    deadline = time.monotonic() + AUDIT_CLOSED_TIMEOUT_S
    while True:
        r = client.get(f"/v1/jobs/{job_id}/audit")
        if r.status_code == 200 and r.content.endswith(MCAP_MAGIC):
            break
        assert time.monotonic() < deadline, f"the audit file of {job_id} was never closed ({r.status_code})"
        time.sleep(0.2)
    import io

    return [(channel.topic, json.loads(msg.data)) for _, channel, msg in
            make_reader(io.BytesIO(r.content)).iter_messages(log_time_order=False)]


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_physics_fault_aborts_the_execution_with_its_reason_in_the_audit(rig, fault):
    srv, port = rig
    flags, words = FAULTS[fault]
    proc = _physics_controller(srv.data_dir, port, flags)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        wait_balance_stream(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        job_id = submit_approved_plan(srv, {"scenario": "stand-10"}, JOB_TIMEOUT_S)
        with srv.client("bob") as bob:
            r = bob.post(f"/v1/jobs/{job_id}/dispatch")
            assert r.status_code == 202, r.text
            done = wait_state(bob, job_id, END_STATES, timeout=JOB_TIMEOUT_S)
            assert done["state"] == "aborted", (done["message"], done["error"])
            assert words in done["error"]["message"], done["error"]
            messages = _audit_messages(bob, job_id)
    finally:
        stop_process(proc)
    states = [body["payload"] for topic, body in messages if topic == "/audit/events" and body["kind"] == "state"]
    assert any(words in json.dumps(s) for s in states if s.get("state") == "aborted")
    balance = [body for topic, body in messages if topic == "/robot/balance"]
    assert balance, "no balance samples in the audit"
    assert all(body["force_left_n"] >= 0 and body["force_right_n"] >= 0 for body in balance)
