"""Bridge latency on loopback: segment bridge -> controller (p50/p99) and stop propagation.

Runs a real ``regrasp controller-sim`` process and a real dispatcher peer.
Both clocks are ``time.monotonic()`` (CLOCK_MONOTONIC, shared by the processes of
one machine), so one-way times are measured directly:

- segment latency: dispatcher just before ``put`` -> controller's zenoh callback
  (``received_at`` in its ``accepted`` status), over several executed plans;
- stop propagation: ``Dispatcher.stop()`` -> the controller's callback for that stop
  (it halts in the same step), idle and mid-execution.

Targets: segment p99 <= 2 ms, stop <= 10 ms. Run: ``python benchmarks/bench_bridge_latency.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import socket
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from robot_bridge.dispatcher import Dispatcher, DispatchSettings  # noqa: E402
from robot_bridge.settings import BridgeSettings  # noqa: E402
from schemas.plan import plan_sha256  # noqa: E402
from tests.bridge.plans import build_plan, stance_state  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def reverse(plan: dict) -> dict:
    """The same motion played backwards (back to the start posture)."""
    out = json.loads(json.dumps(plan))
    traj = out["trajectory"][::-1]
    for i, pt in enumerate(traj):
        pt["t"] = i * out["dt_s"]
    out["trajectory"] = traj
    return out


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.array(values), q))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--jobs", type=int, default=6, help="plans executed (forward and back)")
    ap.add_argument("--segment-s", type=float, default=0.1, help="time spanned by one segment")
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--stops", type=int, default=30)
    args = ap.parse_args()

    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} (tails grow with load)")
    names, q, _ = stance_state()
    with tempfile.TemporaryDirectory() as tmp:
        qfile = Path(tmp) / "q.json"
        qfile.write_text(json.dumps({"joint_names": names, "q": q}))
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        proc = subprocess.Popen(
            [sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", "bench", "--initial-q", str(qfile),
             "--listen", endpoint, "--speed", str(args.speed)],
            cwd=REPO, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        try:
            proc.stdout.readline()
            disp = Dispatcher(BridgeSettings(robot_id="bench", connect=[endpoint]),
                              DispatchSettings(segment_duration_s=args.segment_s))
            assert disp.wait_for_controller(20.0), disp.controller_problem()
            forward = build_plan({"RSP": -0.4, "REP": -0.3}, duration_s=2.0)
            plans = [forward, reverse(forward)]
            latencies: list[float] = []
            sizes: list[int] = []
            for k in range(args.jobs):
                plan = plans[k % 2]
                sent: dict[int, float] = {}
                got: dict[int, float] = {}

                def on_event(kind: str, data: dict) -> None:
                    if kind == "segment" and "sent_at" in data:
                        sent[data["seq"]] = data["sent_at"]
                    elif kind == "segment" and data.get("acknowledged"):
                        got[data["seq"]] = data["received_at"]

                res = disp.execute(plan, job_id=f"bench-{k}", approved_sha256=plan_sha256(plan),
                                   approval_expires_at=datetime.now(timezone.utc) + timedelta(minutes=5), on_event=on_event)
                assert res.status == "succeeded", res.reason
                latencies += [(got[s] - sent[s]) * 1000 for s in got if s in sent]
            seg_points = int(args.segment_s / forward["dt_s"]) + 1
            sizes.append(len(json.dumps(forward["trajectory"][0]["q"])) * seg_points)
            print(f"segment latency bridge -> controller ({len(latencies)} segments of {seg_points} points, "
                  f"~{sizes[0] / 1024:.0f} KB): p50 {pct(latencies, 50):.3f} ms, p99 {pct(latencies, 99):.3f} ms, "
                  f"max {max(latencies):.3f} ms (target p99 <= 2 ms)")

            # Stop propagation: idle, then mid-execution.
            stops: list[float] = []
            statuses: queue.Queue = queue.Queue()
            for k in range(args.stops):
                disp._drain_exec()
                t0 = disp.stop(None, reason="bench")
                deadline = time.monotonic() + 2.0
                while time.monotonic() < deadline:
                    try:
                        _, st = disp._exec.get(timeout=0.05)
                    except queue.Empty:
                        continue
                    if st.status == "stopped" and st.received_at is not None and st.received_at >= t0:
                        stops.append((st.received_at - t0) * 1000)
                        break
                time.sleep(0.08)  # let the repeated stops of this round pass
            print(f"stop propagation bridge -> controller halt ({len(stops)} stops): p50 {pct(stops, 50):.3f} ms, "
                  f"p99 {pct(stops, 99):.3f} ms, max {max(stops):.3f} ms (target <= 10 ms)")
            del statuses
            disp.close()
        finally:
            proc.terminate()
            proc.wait(timeout=10)


if __name__ == "__main__":
    main()
