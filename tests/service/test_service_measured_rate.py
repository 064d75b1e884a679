"""CONTRACT 7 through the real service: the robot's measured joint states reach the job's audit file at 50 or
more per second of motion, whatever the controller's speed.

A real ``regrasp serve`` and ``regrasp controller-sim`` (at 1x and at 8x) on a private loopback endpoint; the
plan comes from the ``stand-S`` test handler (5 ms points). The bridge forwards every measured state it hears
in ``robot_state`` batches; the audit keeps each one on ``/robot/joint_states``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import (
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

pytestmark = pytest.mark.host_pauses(limit_s=0.5)
AUDIT_TIMEOUT_S = 30.0
#: CONTRACT 7: measured joint states per second of motion.
MIN_PER_MOTION_S = 50.0


def _audit_topic_count(srv: Server, job_id: str, topic: str) -> int:
    """Messages on ``topic`` in the job's sealed audit files (bounded wait for the audit pump)."""
    deadline = time.monotonic() + AUDIT_TIMEOUT_S
    while True:
        files = sorted((srv.data_dir / "audit").glob(f"{job_id}*.mcap"))
        if files and all(p.read_bytes().endswith(MCAP_MAGIC) for p in files):
            count = 0
            for path in files:
                with open(path, "rb") as f:
                    count += sum(1 for _ in make_reader(f).iter_messages(topics=[topic]))
            return count
        assert time.monotonic() < deadline, f"the audit of {job_id} was not sealed within {AUDIT_TIMEOUT_S} s"
        time.sleep(0.2)


def _measured(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every measured state the bridge reported for the job, in order."""
    out: list[dict[str, Any]] = []
    for e in events:
        data = e.get("data") or {}
        if e["kind"] == "bridge" and data.get("event") == "robot_state":
            out.extend((data.get("payload") or {}).get("samples") or [])
    return out


@pytest.mark.parametrize("speed", [1, 8])
def test_measured_states_reach_the_audit_at_50_per_second_of_motion(tmp_path: Path, speed: int) -> None:
    port = free_port()
    srv = Server(tmp_path, workers=1, bridge_port=port).start()
    proc = start_controller_sim(srv.data_dir, port, speed=speed)
    try:
        wait_controller_alive(srv, proc, CONTROLLER_UP_TIMEOUT_S)
        job = submit_approved_plan(srv, {"scenario": "stand-3", "threshold_m": 0.03})
        with srv.client("bob") as bob:
            plan = bob.get(f"/v1/jobs/{job}").json()["result"]
            assert bob.post(f"/v1/jobs/{job}/dispatch").status_code == 202
            done = wait_state(bob, job, END_STATES, timeout=60)
            assert done["state"] == "succeeded", (done["message"], done["error"])
            samples = _measured(job_events(bob, job))
        dt = float(plan["dt_s"])
        moving = [s for s in samples if isinstance(s.get("index"), int)]
        assert moving, "no measured state during the motion"
        first, last = min(s["index"] for s in moving), max(s["index"] for s in moving)
        motion_s = (last - first) * dt
        assert motion_s >= 2.5, motion_s  # the whole 3 s plan was played and measured
        # Only states measured while the plan advanced: not the start buffer (held at the first point), not the end.
        inside = [s for s in moving if first < s["index"] < last]
        rate = len(inside) / motion_s
        print(f"speed {speed}x: {len(inside)} measured states over {motion_s:.2f} s of motion = {rate:.1f} per motion-s; "
              f"{len(samples)} in all")
        assert rate >= MIN_PER_MOTION_S, rate
        stamps = [s["stamp"] for s in samples]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)  # each once, in order
        # The audit keeps every one of them on the robot's joint-state channel.
        assert _audit_topic_count(srv, job, "/robot/joint_states") >= len(samples)
    finally:
        stop_process(proc)
        srv.stop()
