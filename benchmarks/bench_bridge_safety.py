"""Safety overheads of the bridge: false aborts under load, and the cost of signing and verifying commands.

1. Sign and verify per segment: the dispatcher's cost to put a production segment
   (0.25 s of points of the robot's joints at 5 ms) on the wire (splice its
   ``expires_at`` into the canonical JSON made once at gate time, Ed25519-sign it),
   and the controller's cost to accept it (verify the signature over the body bytes,
   parse them, validate the segment). The same for the 50 ms heartbeat. Medians and p99 of
   ``--crypto-iterations`` repetitions.

2. False aborts under load: a real ``regrasp controller-sim`` process and a real
   dispatcher, both with the production watchdog (0.25 s: the dispatcher's on the
   controller's heartbeat, the controller's dead-man on the dispatcher's), execute
   ``--runs`` plans (a 2 s arm move, forward then back) while ``--burners``
   processes keep both cores busy and, in the dispatcher's process, a thread does
   GIL-heavy work as the service's API and event threads do (JSON round trips of a
   plan-sized document). The controller is healthy throughout, so every abort is a
   false one. Printed as false aborts per 100 executions with the Wilson 95 %
   interval and the count, per configuration (``--modes``): ``process``, the
   service's arrangement (the dispatcher in a process of its own,
   ``robot_bridge.dispatcher_process``, the GIL-heavy thread in the parent);
   ``in-process``, the dispatcher in the process of the GIL-heavy thread (raised
   thread priority, 0.5 ms switch interval); ``in-process-plain``, the same at a
   normal priority and Python's 5 ms switch interval; ``process-rt``, as ``process`` with
   both peers' bridge threads under SCHED_RR (``realtime_priority``).

The host is shared (other processes run beside this one); the load average and
the CPU time the hypervisor took (steal) are printed with each figure. Keep the
run count modest on a shared machine. Run: ``python benchmarks/bench_bridge_safety.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from robot_bridge.dispatcher import (  # noqa: E402
    Dispatcher,
    DispatchSettings,
    SignedSegment,
    split_segments,
)
from robot_bridge.dispatcher_process import DispatcherProcess  # noqa: E402
from robot_bridge.process_tuning import shorten_switch_interval  # noqa: E402
from robot_bridge.settings import BridgeSettings  # noqa: E402
from robot_bridge.signing import Signer, Verifier, generate_keys, open_signed  # noqa: E402
from schemas.bridge import CommandHeartbeat, TrajectorySegment  # noqa: E402
from schemas.plan import plan_sha256  # noqa: E402
from tests.bridge.plans import build_plan, stance_state  # noqa: E402
from robot_bridge.process_tuning import cpu_competitor_command  # noqa: E402

ROBOT_ID = "benchsafety"
#: SCHED_RR priority of the ``process-rt`` mode (both peers).
REALTIME_PRIORITY = 10
MOVES = {"RSP": -0.4, "REP": -0.3}
MOVE_S = 2.0


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def steal_s() -> float:
    with open("/proc/stat") as f:
        fields = f.readline().split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK") if len(fields) > 8 else 0.0


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    d = 1 + z * z / n
    c = p + z * z / (2 * n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return (max(0.0, (c - h) / d), min(1.0, (c + h) / d))


def pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q * (len(s) - 1))))]


def crypto_costs(iterations: int, signer: Signer, verifier: Verifier) -> None:
    plan = build_plan(MOVES, duration_s=MOVE_S)
    seg = split_segments(plan, "bench-job", plan_sha256(plan), 1, DispatchSettings().segment_duration_s)[1]
    ready = SignedSegment(seg)
    sign_us, verify_us, schema_us, hb_sign_us, hb_verify_us = [], [], [], [], []
    wire = b""
    for _ in range(iterations):
        t0 = time.perf_counter()
        wire = ready.wire(signer, time.time() + 1.0)
        t1 = time.perf_counter()
        msg, problem = open_signed(wire, verifier)
        assert problem is None
        t1b = time.perf_counter()
        TrajectorySegment.model_validate(msg)
        t2 = time.perf_counter()
        schema_us.append((t2 - t1b) * 1e6)
        now = time.time()
        hb = signer.encode({"job_id": "bench-job", "seq": 1, "t": now, "expires_at": now + 0.25})
        t3 = time.perf_counter()
        m, problem = open_signed(hb, verifier)
        assert problem is None
        CommandHeartbeat.model_validate(m)
        t4 = time.perf_counter()
        sign_us.append((t1 - t0) * 1e6)
        verify_us.append((t1b - t1) * 1e6)
        hb_sign_us.append((t3 - t2) * 1e6)
        hb_verify_us.append((t4 - t3) * 1e6)
    print(f"segment of {len(seg.points)} points x {len(seg.joint_names)} joints ({len(wire) / 1000:.1f} kB signed), "
          f"{iterations} repetitions, load average {os.getloadavg()[0]:.1f}:")
    print(f"  dispatcher, expiry + Ed25519 signature per segment: median {statistics.median(sign_us):.0f} us, "
          f"p99 {pct(sign_us, 0.99):.0f} us")
    print(f"  controller, verify + parse per segment: median {statistics.median(verify_us):.0f} us, "
          f"p99 {pct(verify_us, 0.99):.0f} us (then the segment's own schema checks, as before signing: median "
          f"{statistics.median(schema_us):.0f} us)")
    print(f"  heartbeat: sign median {statistics.median(hb_sign_us):.0f} us, verify (+ schema) median "
          f"{statistics.median(hb_verify_us):.0f} us")


def burner() -> subprocess.Popen:
    return subprocess.Popen(cpu_competitor_command())


def gil_load(stop: threading.Event, doc: dict) -> None:
    """What the service's API and event threads do between heartbeats: pure-Python JSON work."""
    while not stop.is_set():
        json.loads(json.dumps(doc))


def start_controller(qfile: Path, public: Path, nice: str | None, realtime: int | None = None
                     ) -> tuple[subprocess.Popen, str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    if nice is not None:
        env["REGRASP_BRIDGE_THREAD_NICE"] = nice
    if realtime is not None:
        env["REGRASP_BRIDGE_REALTIME_PRIORITY"] = str(realtime)
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", ROBOT_ID, "--initial-q", str(qfile),
         "--listen", endpoint, "--speed", "1", "--trusted-key", str(public)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    line = proc.stdout.readline()
    assert line.startswith("{") and json.loads(line)["ready"], line
    return proc, endpoint


def false_aborts(mode: str, runs: int, burners: int, service_load: bool, qfile: Path, keys: tuple[Path, Path]) -> None:
    plain = mode == "in-process-plain"
    realtime = mode == "process-rt"
    nice = "0" if plain else None  # 0: a normal process's own priority, i.e. not raised
    proc, endpoint = start_controller(qfile, keys[1], nice, REALTIME_PRIORITY if realtime else None)
    settings = BridgeSettings(robot_id=ROBOT_ID, connect=[endpoint], signing_key=keys[0],
                              **({"thread_nice": 0} if plain else {}),
                              **({"realtime_priority": REALTIME_PRIORITY} if realtime else {}))
    sys.setswitchinterval(0.005)
    if mode == "in-process":
        shorten_switch_interval()

    def make(s: BridgeSettings):
        return DispatcherProcess(s) if mode.startswith("process") else Dispatcher(s)

    disp = make(settings)
    forward = build_plan(MOVES, duration_s=MOVE_S)
    back = json.loads(json.dumps(forward))
    back["trajectory"] = [dict(p, q=q["q"]) for p, q in zip(forward["trajectory"], reversed(forward["trajectory"]))]
    plans = [forward, back]
    hogs = [burner() for _ in range(burners)]
    stop = threading.Event()
    loader = threading.Thread(target=gil_load, args=(stop, forward), daemon=True)
    aborts: list[str] = []
    done = 0
    try:
        assert disp.wait_for_controller(20.0), disp.controller_problem()
        if service_load:
            loader.start()
        steal0, t0 = steal_s(), time.monotonic()
        loads = []
        k = 0
        while done < runs:
            plan = plans[k % 2]
            res = disp.execute(plan, job_id=f"load-{mode}-{k}", approved_sha256=plan_sha256(plan),
                               approval_expires_at=datetime.now(timezone.utc) + timedelta(minutes=5))
            k += 1
            loads.append(os.getloadavg()[0])
            if res.status == "succeeded":
                done += 1
                continue
            done += 1
            aborts.append(res.reason)
            # the abort left the arm mid-way: start over with a fresh controller standing in the stance
            proc.terminate()
            proc.wait(10)
            disp.close()
            proc, endpoint = start_controller(qfile, keys[1], nice)
            disp = make(settings.model_copy(update={"connect": [endpoint]}))
            assert disp.wait_for_controller(20.0), disp.controller_problem()
            k = 0
        elapsed, stolen = time.monotonic() - t0, steal_s() - steal0
    finally:
        stop.set()
        for h in hogs:
            h.kill()
            h.wait()
        disp.close()
        proc.terminate()
        proc.wait(10)
    lo, hi = wilson(len(aborts), runs)
    print(f"mode {mode}: false aborts {len(aborts)} of {runs} executions = {100 * len(aborts) / runs:.1f} per 100 "
          f"(95 % interval {100 * lo:.1f} to {100 * hi:.1f}); {burners} busy processes"
          f"{' + GIL-heavy thread in the dispatcher process' if service_load else ''}, load average "
          f"{statistics.median(loads):.1f} (median), steal {stolen / max(elapsed, 1e-9) * 100:.1f} % of {elapsed:.0f} s")
    for reason in aborts:
        print(f"    abort: {reason}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20, help="executions per mode (keep it modest on a shared host)")
    ap.add_argument("--burners", type=int, default=4, help="busy processes beside the bridge (2 cores: both busy)")
    ap.add_argument("--no-service-load", action="store_true", help="no GIL-heavy thread in the dispatcher's process")
    ap.add_argument("--modes", default="process,in-process")
    ap.add_argument("--crypto-iterations", type=int, default=2000)
    args = ap.parse_args()
    print(f"machine: {os.cpu_count()} cores, shared with other work; load average {os.getloadavg()[0]:.1f}; "
          f"running as uid {os.getuid()} (raising thread priority needs CAP_SYS_NICE)")
    with tempfile.TemporaryDirectory() as tmp:
        private, public = generate_keys(Path(tmp) / "keys")
        crypto_costs(args.crypto_iterations, Signer.from_file(private), Verifier.from_file(public))
        if args.runs <= 0:
            return
        names, q, _ = stance_state()
        qfile = Path(tmp) / "q.json"
        qfile.write_text(json.dumps({"joint_names": names, "q": q}))
        for mode in args.modes.split(","):
            false_aborts(mode.strip(), args.runs, args.burners, not args.no_service_load, qfile, (private, public))


if __name__ == "__main__":
    main()
