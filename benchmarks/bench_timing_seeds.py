"""The plan timing over several seeds: each built-in scenario's search result timed rest to rest (the search's
trapezoids) and by the plan's timing, per seed, with the hands of its default plan.

The README's duration figures are seed 1's. A seed decides the search's samples, and so the plan's pieces (a seed
can give a plan with a regrasp more) and the paths of its motions; this prints how the timing does across them:
per seed the plan's segments, its rest-to-rest duration, the timed duration and their ratio; per scenario the
median ratio with its range (over n seeds the range covers the median with probability 1 - 2^(1-n), 97 % at 6),
and how many seeds meet the issue's targets (at most 0.5x rest to rest; the duration at most half of the first
measured plans': ``TARGET_S``). Durations depend on the seed only.

    python benchmarks/bench_timing_seeds.py
    python benchmarks/bench_timing_seeds.py --seeds 1 2 3 --scenario upright crouched
"""

from __future__ import annotations

import argparse
import statistics

from planner.blas_threads import one_blas_thread
from planner.jobs.plan_job import build_task, timing_settings, timing_zmp_margin
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.plan_assembly import assemble
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.scene.scenarios import load_builtin, with_overrides

#: the hands of each scenario's seed-1 plan (``hands: auto``'s survey answer, or the scenario's own)
HANDS = {"upright": "right-right", "staggered": "left-left", "crouched": "left-right", "one-legged": "right-left",
         "drill-handover": "right-left"}
#: half of each scenario's first measured plan duration (rest to rest, before the plan timing), s
TARGET_S = {"upright": 9.5, "staggered": 9.15, "crouched": 18.1, "one-legged": 9.45, "drill-handover": 16.85}


@one_blas_thread  # as the CLI's plans run (planner/blas_threads.py)
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", nargs="+", default=list(HANDS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--hands", action="append", default=[], metavar="NAME=HANDS", help="other hands for a scenario")
    args = ap.parse_args()
    hands_of = {**HANDS, **dict(item.split("=", 1) for item in args.hands)}
    print(f"{'scenario':15s} {'hands':12s} {'seed':>4s} {'segments':>8s} {'rest to rest s':>14s} {'timed s':>8s} "
          f"{'ratio':>6s}")
    summary = []
    for name in args.scenario:
        hands = hands_of[name]
        ratios, timed = [], []
        for seed in args.seeds:
            scenario = with_overrides(load_builtin(name), seed=seed, hands=hands)
            task = build_task(scenario)
            res = HandConfigPlanner(task, hands).plan()
            if res.status != "solved":
                print(f"{name:15s} {hands:12s} {seed:4d} {res.status}")
                continue
            start = task.placements[task.start_id]
            dt = task.settings.timing.dt_s
            rest = float(assemble(res.pieces, task.evaluator, dt, start).t[-1])
            timing = PlanTimer(task, timing_settings(scenario, task.settings.plan_timing), scenario.speed_scale,
                               timing_zmp_margin(scenario, task.threshold_m), dt).time_plan(res.pieces)
            traj = assemble(timing.pieces, task.evaluator, dt, start)
            duration, segments = float(traj.t[-1]), len(traj.segments)  # the plan's segments, as it records them
            ratios.append(duration / rest)
            timed.append(duration)
            print(f"{name:15s} {hands:12s} {seed:4d} {segments:8d} {rest:14.2f} {duration:8.2f} {duration / rest:6.2f}")
        if ratios:
            summary.append((name, ratios, timed))
    print(f"\n{'scenario':15s} {'n':>2s} {'median ratio (range)':>22s} {'<= 0.5x':>8s} {'median s (range)':>24s} "
          f"{'target s':>8s} {'met':>4s}")
    for name, ratios, timed in summary:
        n = len(ratios)
        met = sum(t <= TARGET_S[name] for t in timed)
        print(f"{name:15s} {n:2d} {statistics.median(ratios):8.2f} ({min(ratios):.2f}-{max(ratios):.2f}) "
              f"{sum(r <= 0.5 for r in ratios):4d}/{n:<3d} {statistics.median(timed):10.2f} "
              f"({min(timed):.2f}-{max(timed):.2f}) {TARGET_S[name]:8.2f} {met:2d}/{n}")


if __name__ == "__main__":
    main()
