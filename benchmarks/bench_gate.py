"""Safety gate throughput: samples checked per second on a 60 s trajectory at 200 Hz.

Target: >= 100,000 samples/s end to end (a 60 s trajectory, 12,000 samples at 5 ms,
checked in <= 0.12 s from its stored bytes, every check included). Prints the numeric
checks (parse, limits, kinematics, CoM margin, ZMP) apart from the canonical-JSON
SHA-256 of a plan given as a dict, then the path the dispatcher takes: the stored
canonical bytes hashed as they are (in a thread, alongside the decode), decoded into the checked
fields (msgspec), every check (the torque and grip checks in a thread, alongside the others). Rates are given per
5 ms controller sample and per gate sample (the midpoints too).
Run: ``python benchmarks/bench_gate.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from robot_bridge.gate import GateSettings, SafetyGate  # noqa: E402
from schemas.plan import canonical_json  # noqa: E402
from tests.bridge.plans import build_plan  # noqa: E402  (builds a realistic plan with the planner)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=60.0, help="trajectory duration")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    plan = build_plan({"RSP": -0.8, "REP": -0.4, "WY": 0.3, "LSP": -0.5}, duration_s=args.seconds - 0.1, mass_kg=4.0,
                      holding="right", threshold_m=0.02)
    n = len(plan["trajectory"])
    print(f"plan: {n} points at 200 Hz ({plan['trajectory'][-1]['t']:.1f} s), {len(plan['robot']['joint_names'])} joints")
    for oversample in (1, 2):
        gate = SafetyGate(GateSettings(oversample=oversample))
        gate.check(plan, offline=True)  # warm the caches (URDF parse)
        totals, numeric, hashes, stab = [], [], [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            v = gate.check(plan, offline=True)
            totals.append(time.perf_counter() - t0)
            timing = v.stats["timing"]
            hashes.append(timing["hash_s"])
            numeric.append(totals[-1] - timing["hash_s"])
            stab.append(timing["stability_s"])
        assert v.passed, v.summary()
        med = statistics.median(numeric)
        label = "controller period (5 ms)" if oversample == 1 else "5 ms + midpoints"
        print(f"samples: {v.samples} ({label})")
        print(f"  numeric checks: {med * 1000:.1f} ms median -> {v.samples / med:,.0f} samples/s "
              f"(kinematics+margin+ZMP {statistics.median(stab) * 1000:.1f} ms: {v.samples / statistics.median(stab):,.0f} samples/s)")
        print(f"  plan SHA-256 (canonical JSON): {statistics.median(hashes) * 1000:.1f} ms; whole check {statistics.median(totals) * 1000:.1f} ms")
    raw = canonical_json(plan)
    gate = SafetyGate()
    times, hashes, loads, checks = [], [], [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        v, _ = gate.check_json(raw, offline=True)
        times.append(time.perf_counter() - t0)
        hashes.append(v.stats["timing"]["hash_s"])
        loads.append(v.stats["timing"]["json_s"])
        checks.append(v.elapsed_s)
    assert v.passed, v.summary()
    med = statistics.median(times)
    print(f"canonical-bytes path (check_json: sha256 of the stored bytes + typed decode + all checks), {len(raw) / 1e6:.1f} MB: "
          f"{med * 1000:.1f} ms median (min {min(times) * 1000:.1f} ms) -> {n / med:,.0f} samples/s at 5 ms "
          f"({v.samples / med:,.0f} gate samples/s with midpoints) end to end (sha256 alongside the decode "
          f"{statistics.median(hashes) * 1000:.1f} ms, decode {statistics.median(loads) * 1000:.1f} ms, checks "
          f"{statistics.median(checks) * 1000:.1f} ms)")
    target = 100_000
    print(f"target: >= {target:,} samples/s")


if __name__ == "__main__":
    main()
