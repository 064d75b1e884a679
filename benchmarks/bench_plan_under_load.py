"""A plan's trajectory does not depend on the machine's load: the same scenario and seed planned
alone, then with CPU-bound competitors (``while True: pass``) on every core, by the installed
command line (``regrasp plan``) in a fresh process each time.

Target: the same trajectory (every point's ``q``) both times, solved; the built-in scenarios carry
no time limit, so only the seed and the iteration caps decide.
Run: python benchmarks/bench_plan_under_load.py [--scenario crouched] [--hands left-right] [--seed 3] [--competitors 2]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from robot_bridge.process_tuning import cpu_competitor_command


def plan_once(args: argparse.Namespace, out: Path) -> dict:
    cmd = [sys.executable, "-m", "service.cli.main", "plan", "--scenario", args.scenario, "--seed", str(args.seed),
           "--out", str(out), "--quiet"]
    if args.hands:
        cmd += ["--hands", args.hands]
    t0 = time.perf_counter()
    subprocess.run(cmd, stdout=subprocess.DEVNULL, check=False)
    wall = time.perf_counter() - t0
    doc = json.loads(out.read_text())
    qs = json.dumps([p["q"] for p in doc.get("trajectory", [])])
    return {"status": doc["status"], "failure": (doc.get("failure") or {}).get("code"), "points": len(doc.get("trajectory", [])),
            "min_margin_mm": None if doc.get("min_margin_m") is None else round(doc["min_margin_m"] * 1000, 1),
            "q_sha256": hashlib.sha256(qs.encode()).hexdigest()[:16], "wall_s": round(wall, 1)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenario", default="crouched")
    ap.add_argument("--hands", default="left-right")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--competitors", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        quiet = plan_once(args, Path(tmp) / "quiet.json")
        print(f"alone:           {quiet}", flush=True)
        spinners = [subprocess.Popen(cpu_competitor_command()) for _ in range(args.competitors)]
        try:
            loaded = plan_once(args, Path(tmp) / "loaded.json")
        finally:
            for p in spinners:
                p.kill()
                p.wait()
        print(f"{args.competitors} competitors:   {loaded}")
    same = quiet["q_sha256"] == loaded["q_sha256"] and quiet["status"] == loaded["status"]
    print(f"{args.scenario} --hands {args.hands} --seed {args.seed}: same trajectory alone and loaded: {same}; "
          f"status {quiet['status']}; wall {quiet['wall_s']} s alone, {loaded['wall_s']} s loaded")


if __name__ == "__main__":
    main()
