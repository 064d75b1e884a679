"""Stability survey speed: evaluated states per second (collision checks included), and the
wall time of a survey of all four configurations with N states each (default 20,000).

Run: python benchmarks/bench_survey.py [--scenario upright] [--states 20000] [--workers 2]
Target (2 cores, grasp cache warm): 4 x 20,000 states in <= 10 s.
"""

from __future__ import annotations

import argparse
import time

from planner.scene.scenarios import load_builtin
from planner.survey.runner import run_survey


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenario", default="upright")
    ap.add_argument("--states", type=int, default=20_000)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    sc = load_builtin(args.scenario)
    run_survey(sc, states=50, workers=1, hands=["right-right"])  # warm the grasp cache
    t0 = time.perf_counter()
    doc, _ = run_survey(sc, states=args.states, workers=args.workers)
    wall = time.perf_counter() - t0
    print(f"survey of {args.scenario!r}: 4 configurations x {args.states} states, {args.workers} workers: {wall:.1f} s wall")
    total_explore = 0.0
    total_states = 0
    for row in doc["rows"]:
        st = doc["stats"]["configurations"][row["hands"]]
        if row["ratio"] is None:
            print(f"  {row['hands']:<12} n/a: {row['reason']}")
            continue
        total_explore += st["exploration_s"]
        total_states += st["evaluated"]
        print(f"  {row['hands']:<12} R={row['ratio']:.4f}  key poses {st['key_poses_s']:.1f} s, exploration "
              f"{st['exploration_s']:.1f} s = {st['states_per_s']:,.0f} states/s (rejected: {st['rejected']})")
    if total_explore:
        print(f"  exploration alone: {total_states / total_explore:,.0f} evaluated states/s per core (collision checks included)")


if __name__ == "__main__":
    main()
