"""Stability survey speed: a converged survey of one stance, and `hands: auto` planning once it is cached.

Run: python benchmarks/bench_survey.py [--scenario upright] [--workers 2] [--ci-half-width 0.02] [--plans 5]
         [--seeds-max 256] [--leg-cap 20000] [--goal-aim tree|root] [--no-limits]
Targets (2 cores): a converged survey of one stance (4 configurations, +-0.02) within 120 s; a
`hands: auto` plan within 3 s (warm median) once the task's survey is cached.
Prints the survey's wall time, then per configuration: R and its interval, the seeds it took,
states per seed (min / median / max), the spread of R between seeds, the legs' largest seed, the
repeated poses left out, the key poses' time and the exploration's CPU time and states per second.
`--goal-aim root` runs the exploration with the goal-biased samples aimed at the other tree's root
(the aim the survey had before it aimed at a random node of the other tree), for comparison.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numpy as np

from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.scene.scenarios import load_builtin, with_overrides
from planner.survey.counting import CountingSettings
from planner.survey.runner import run_survey


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenario", default="upright")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--ci-half-width", type=float, default=0.02)
    ap.add_argument("--seeds-max", type=int, default=256)
    ap.add_argument("--leg-cap", type=int, default=20_000)
    ap.add_argument("--goal-aim", choices=("tree", "root"), default="tree")
    ap.add_argument("--no-limits", action="store_true", help="without effort and grip limits (as the paper's tables)")
    ap.add_argument("--plans", type=int, default=5, help="hands: auto plans timed once the survey is cached (0: none)")
    args = ap.parse_args()
    os.environ.setdefault("REGRASP_SURVEY_CACHE_DIR", tempfile.mkdtemp(prefix="bench-survey-"))
    sc = with_overrides(load_builtin(args.scenario), survey={"ci_half_width": args.ci_half_width, "seeds_max": args.seeds_max,
                                                             "leg_cap_states": args.leg_cap})
    counting = CountingSettings(goal_aim=args.goal_aim)
    run_survey(sc, states=20, workers=1, hands=["right-right"], keep_states=False)  # warm the grasp cache and kernels
    t0 = time.perf_counter()
    doc, _ = run_survey(sc, workers=args.workers, keep_states=False, counting=counting, no_limits=args.no_limits)
    wall = time.perf_counter() - t0
    configs = doc["stats"]["configurations"]
    states = sum(configs[r["hands"]].get("evaluated", 0) for r in doc["rows"])
    cpu = sum(configs[r["hands"]].get("exploration_s", 0.0) for r in doc["rows"])
    print(f"converged survey of {args.scenario!r} (+-{args.ci_half_width}, goal aim {args.goal_aim}, "
          f"limits {doc['limits']}), {args.workers} workers: {wall:.1f} s wall, {states:,} states counted, "
          f"exploration {cpu:.1f} s CPU ({states / max(cpu, 1e-9):,.0f} states/s per core)")
    for row in doc["rows"]:
        if row["ratio"] is None:
            print(f"  {row['hands']:<12} n/a: {row['reason']}")
            continue
        st = configs[row["hands"]]
        n = np.array([p["stable"] + p["unstable"] for p in row["per_seed"]])
        r = np.array([p["stable"] / max(p["stable"] + p["unstable"], 1) for p in row["per_seed"]])
        counted = [[leg["counted"] for leg in seed] for seed in st["legs_per_seed"]]  # seeds may end after fewer legs
        largest = [max(seed[k] for seed in counted if len(seed) > k) for k in range(max(map(len, counted), default=0))]
        repeats = sum(leg.get("repeats", 0) for seed in st["legs_per_seed"] for leg in seed)
        print(f"  {row['hands']:<12} R={row['ratio']:.4f} [{row['ratio_ci95'][0]:.4f}, {row['ratio_ci95'][1]:.4f}] "
              f"seeds {row['seeds']}{'' if row['converged'] else ' (not converged)'}, states/seed min {n.min()} "
              f"median {np.median(n):.0f} max {n.max()}, per-seed R sd {r.std():.3f}, solved {st['solved_seeds']}/{row['seeds']}")
        print(f"  {'':<12} legs' largest seed {largest}, repeats left out {repeats:,}, "
              f"key poses {st['key_poses_s']:.2f} s, exploration {st['exploration_s']:.1f} s CPU, "
              f"{st['states_per_s']:,.0f} states/s per core")
    print(f"  recommended {doc['recommended']}, indistinguishable {doc['indistinguishable']}")
    if args.plans:
        from planner.survey.cache import SurveyCache

        SurveyCache.default().put(SurveyCache.default().key_for(sc), doc)
        times = []
        for _ in range(args.plans):
            t = time.perf_counter()
            plan = plan_scenario(sc, PlanOptions(hands="auto"))
            times.append(time.perf_counter() - t)
        print(f"hands: auto plans with the survey cached: median {statistics.median(times):.2f} s over {len(times)} "
              f"(min {min(times):.2f}, max {max(times):.2f}); hands {plan['hands']}, status {plan['status']}")


if __name__ == "__main__":
    main()
