"""The dispatcher's deadlines under load: its heartbeat (the controller's dead-man) and its loss detection.

A real ``regrasp controller-sim`` (production 250 ms dead-man, speed 1) and a real dispatcher execute a
``--plan-s`` plan ``--runs`` times while ``--competitors`` CPU-bound processes (``while True: pass``) keep
the cores busy. A spy peer (its own zenoh session, connected to both) records every heartbeat the
dispatcher sends on ``cmd/heartbeat``, its send time (the message's ``t``) and its arrival.

1. Heartbeat deadline misses per 1,000 heartbeats: a heartbeat is late when it went out more than
   ``--late-ms`` (25 ms) after its 50 ms period since the one before (sender's clock), and a dead-man
   miss when the gap exceeded the controller's 250 ms watchdog (the controller would stop a healthy
   execution). Counted by the sender's times and, separately, by the arrival times at the spy.
2. Loss detection: ``--loss-runs`` executions in which the controller's heartbeat freezes after 0.5 s
   (``--freeze-heartbeat-after-s``); the time from the last controller heartbeat the spy saw to the
   dispatcher's stop arriving at the spy, against the 300 ms deadline (250 ms watchdog + 50 ms).

Per configuration (``--modes``): ``process``, the service's arrangement (the dispatcher in a process of
its own, ``robot_bridge.dispatcher_process``); ``in-process``, the dispatcher in this process; each with
the bridge's threads under SCHED_RR where allowed (the default) or, with ``-plain``, at normal priority
(``realtime_priority`` and ``thread_nice`` off), to show what the priority does. Counts come with their
Wilson 95 % interval. Run: ``python benchmarks/bench_dispatch_deadlines.py`` (about 6 minutes).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from robot_bridge.dispatcher import Dispatcher  # noqa: E402
from robot_bridge.dispatcher_process import DispatcherProcess  # noqa: E402
from robot_bridge.settings import BridgeSettings, Keys  # noqa: E402
from robot_bridge.signing import generate_keys  # noqa: E402
from robot_bridge.zenoh_session import open_session  # noqa: E402
from schemas.plan import plan_sha256  # noqa: E402
from tests.bridge.plans import build_plan, stance_state  # noqa: E402
from robot_bridge.process_tuning import cpu_competitor_command  # noqa: E402

ROBOT_ID = "benchdeadlines"
#: The controller's dead-man (production) and the contract's loss deadline, s.
WATCHDOG_S = 0.25
LOSS_DEADLINE_S = 0.30


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    d = 1 + z * z / n
    c = p + z * z / (2 * n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return (max(0.0, (c - h) / d), min(1.0, (c + h) / d))


def start_controller(qfile: Path, public: Path, *flags: str) -> tuple[subprocess.Popen, str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "controller-sim", "--robot-id", ROBOT_ID, "--initial-q", str(qfile),
         "--listen", endpoint, "--speed", "1", "--trusted-key", str(public), *flags],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    line = proc.stdout.readline()
    assert line.startswith("{") and json.loads(line)["ready"], line
    return proc, endpoint


class Spy:
    """A zenoh peer recording the dispatcher's heartbeats and stops, and the controller's heartbeats."""

    def __init__(self, endpoint: str, controller: str):
        from robot_bridge.process_tuning import raise_thread_priority, use_realtime_scheduling

        # zenoh's threads inherit this thread's priority: the spy must not be what is late
        raise_thread_priority(-10)
        use_realtime_scheduling(10)
        self.session = open_session(BridgeSettings(robot_id=ROBOT_ID, listen=[endpoint], connect=[controller]))
        keys = Keys(ROBOT_ID)
        self.lock = threading.Lock()
        self.beats: list[tuple[str, float, float]] = []  # (job, sender unix t, arrival monotonic)
        self.stops: list[tuple[str | None, float]] = []
        self.controller_beats: list[float] = []
        self.subs = [self.session.declare_subscriber(keys.command_heartbeat, self._beat),
                     self.session.declare_subscriber(keys.stop, self._stop),
                     self.session.declare_subscriber(keys.heartbeat, self._controller_beat)]

    def _beat(self, sample) -> None:
        doc = json.loads(sample.payload.to_bytes())
        with self.lock:
            self.beats.append((doc["job_id"], float(doc["t"]), time.monotonic()))

    def _stop(self, sample) -> None:
        doc = json.loads(sample.payload.to_bytes())
        with self.lock:
            self.stops.append((doc.get("job_id"), time.monotonic()))

    def _controller_beat(self, sample) -> None:
        with self.lock:
            self.controller_beats.append(time.monotonic())

    def close(self) -> None:
        self.session.close()


def gaps_by_job(beats: list[tuple[str, float, float]], column: int) -> list[float]:
    by: dict[str, list[float]] = {}
    for b in beats:
        by.setdefault(b[0], []).append(b[column])
    out: list[float] = []
    for times in by.values():
        times.sort()
        out += [b - a for a, b in zip(times, times[1:])]
    return out


def make_dispatcher(mode: str, settings: BridgeSettings):
    return DispatcherProcess(settings) if mode.startswith("process") else Dispatcher(settings)


def bench_mode(mode: str, args: argparse.Namespace, qfile: Path, keys: tuple[Path, Path]) -> None:
    plain = mode.endswith("-plain")
    prio = {"thread_nice": None, "realtime_priority": None} if plain else {}
    spy_endpoint = f"tcp/127.0.0.1:{free_port()}"
    plan = build_plan({"RSP": -0.4, "REP": -0.3}, duration_s=args.plan_s)
    back = json.loads(json.dumps(plan))
    back["trajectory"] = [dict(p, q=q["q"]) for p, q in zip(plan["trajectory"], reversed(plan["trajectory"]))]
    hogs = [subprocess.Popen(cpu_competitor_command()) for _ in range(args.competitors)]
    period = BridgeSettings().heartbeat_period_s
    try:
        # 1. heartbeats of healthy executions
        proc, endpoint = start_controller(qfile, keys[1])
        spy = Spy(spy_endpoint, endpoint)
        disp = make_dispatcher(mode, BridgeSettings(robot_id=ROBOT_ID, connect=[endpoint, spy_endpoint],
                                                    signing_key=keys[0], watchdog_timeout_s=WATCHDOG_S, **prio))
        aborts: list[str] = []
        try:
            assert disp.wait_for_controller(20.0), disp.controller_problem()
            for k in range(args.runs):
                p = (plan, back)[k % 2]
                res = disp.execute(p, job_id=f"{mode}-{k}", approved_sha256=plan_sha256(p),
                                   approval_expires_at=datetime.now(timezone.utc) + timedelta(minutes=5))
                if res.status != "succeeded":
                    aborts.append(res.reason)
                    break  # the arm stopped mid-way: the next plan would not start where it stands
        finally:
            disp.close()
            proc.terminate()
            proc.wait(10)
        with spy.lock:
            beats = list(spy.beats)
        spy.close()
        for label, column in (("sent", 1), ("arrived", 2)):
            gaps = gaps_by_job(beats, column)
            n = len(gaps)
            late = sum(g > period + args.late_ms / 1000 for g in gaps)
            dead = sum(g > WATCHDOG_S for g in gaps)
            lo, hi = wilson(late, n)
            dlo, dhi = wilson(dead, n)
            worst = max(gaps) if gaps else float("nan")
            print(f"{mode:18s} heartbeats {label:7s}: {n} gaps, late (> {period * 1000 + args.late_ms:.0f} ms) "
                  f"{1000 * late / max(n, 1):.1f} per 1,000 [{1000 * lo:.1f}, {1000 * hi:.1f}] ({late}), dead-man misses "
                  f"(> {WATCHDOG_S * 1000:.0f} ms) {1000 * dead / max(n, 1):.1f} per 1,000 [{1000 * dlo:.1f}, "
                  f"{1000 * dhi:.1f}] ({dead}), worst gap {worst * 1000:.0f} ms")
        for reason in aborts:
            print(f"{mode:18s}   execution aborted: {reason}")

        # 2. loss detection: the controller's heartbeat freezes mid-execution
        latencies: list[float] = []
        for k in range(args.loss_runs):
            proc, endpoint = start_controller(qfile, keys[1], "--freeze-heartbeat-after-s", "0.5")
            spy_at = f"tcp/127.0.0.1:{free_port()}"
            spy = Spy(spy_at, endpoint)
            disp = make_dispatcher(mode, BridgeSettings(robot_id=ROBOT_ID, connect=[endpoint, spy_at],
                                                        signing_key=keys[0], watchdog_timeout_s=WATCHDOG_S, **prio))
            try:
                assert disp.wait_for_controller(20.0), disp.controller_problem()
                res = disp.execute(plan, job_id=f"{mode}-loss-{k}", approved_sha256=plan_sha256(plan),
                                   approval_expires_at=datetime.now(timezone.utc) + timedelta(minutes=5))
                time.sleep(0.2)
                with spy.lock:
                    stops = [t for job, t in spy.stops if job == f"{mode}-loss-{k}"]
                    beats_seen = [t for t in spy.controller_beats if not stops or t < stops[0]]
                if res.status == "aborted" and stops and beats_seen:
                    latencies.append(stops[0] - beats_seen[-1])
                else:
                    print(f"{mode:18s}   loss run {k}: {res.status} {res.reason!r}, stops seen {len(stops)}")
            finally:
                disp.close()
                spy.close()
                proc.terminate()
                proc.wait(10)
        if latencies:
            over = sum(v > LOSS_DEADLINE_S for v in latencies)
            lo, hi = wilson(over, len(latencies))
            print(f"{mode:18s} loss detection: stop {min(latencies) * 1000:.0f}-{max(latencies) * 1000:.0f} ms after "
                  f"the last controller heartbeat (median {sorted(latencies)[len(latencies) // 2] * 1000:.0f} ms), over "
                  f"the {LOSS_DEADLINE_S * 1000:.0f} ms deadline {over} of {len(latencies)} "
                  f"(95 % interval {100 * lo:.0f}-{100 * hi:.0f} %)")
    finally:
        for h in hogs:
            h.kill()
            h.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--competitors", type=int, default=2, help="CPU-bound processes beside the bridge")
    ap.add_argument("--runs", type=int, default=5, help="healthy executions per mode (heartbeats every 50 ms)")
    ap.add_argument("--plan-s", type=float, default=10.0, help="length of each healthy execution's plan, s")
    ap.add_argument("--loss-runs", type=int, default=5, help="executions whose controller heartbeat freezes")
    ap.add_argument("--late-ms", type=float, default=25.0, help="a heartbeat later than its period by this is late")
    ap.add_argument("--modes", default="process,in-process,process-plain,in-process-plain")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        keys = generate_keys(tmpdir / "keys")
        names, q, _ = stance_state()
        qfile = tmpdir / "q.json"
        qfile.write_text(json.dumps({"joint_names": names, "q": q}))
        print(f"{args.competitors} CPU-bound competitors on {os.cpu_count()} cores; heartbeat period "
              f"{BridgeSettings().heartbeat_period_s * 1000:.0f} ms, dead-man {WATCHDOG_S * 1000:.0f} ms")
        for mode in args.modes.split(","):
            bench_mode(mode.strip(), args, qfile, keys)


if __name__ == "__main__":
    main()
