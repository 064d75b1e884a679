"""The physics twin over several seeds: each built-in scenario planned with its default hands (``hands: auto``'s
survey answer, which belongs to the task and is cached, or the scenario's own) for each seed, played by
``regrasp simulate`` with the stabilizer, and its smallest centre-of-pressure margin over the plan's static minimum
(``cop_margin_ratio``). The issue's target is at least 0.75 on every plan; the README's figure is seed 1's
(``benchmarks/bench_physics.py --section hold``), this shows how it holds across the plans a seed gives. Per seed:
the plan's hands, duration, static minimum, the twin's smallest CoP margin, when, and the ratio; per scenario the
smallest and the median ratio of the runs that stood (over n seeds the range covers the median with probability
1 - 2^(1-n), 97 % at 6), how many seeds keep 0.75 and how many faulted. Everything printed depends on the seed only
(the twin is deterministic).

    python benchmarks/bench_twin_seeds.py
    python benchmarks/bench_twin_seeds.py --scenario one-legged --hands right-right --seeds 1 2 3
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planner.blas_threads import one_blas_thread  # noqa: E402
from planner.jobs.plan_job import PlanOptions, plan_scenario  # noqa: E402
from planner.scene.scenarios import load_builtin  # noqa: E402
from robot_bridge.physics.simulate import simulate  # noqa: E402

SCENARIOS = ("upright", "staggered", "crouched", "one-legged", "drill-handover")
#: the twin's target: the smallest CoP margin at least this share of the plan's static minimum
TARGET = 0.75


@one_blas_thread  # as the CLI's plans run (planner/blas_threads.py)
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--hands", default=None, help="these hands for every scenario (default: each one's own)")
    args = ap.parse_args()
    print(f"{'scenario':15s} {'hands':12s} {'seed':>4s} {'duration s':>10s} {'static min mm':>13s} "
          f"{'min CoP mm':>10s} {'at s':>6s} {'ratio':>6s}")
    summary = []
    for name in args.scenario:
        ratios, faults = [], 0
        for seed in args.seeds:
            plan = plan_scenario(load_builtin(name), PlanOptions(hands=args.hands, seed=seed))
            if plan["status"] != "solved":
                print(f"{name:15s} {'':12s} {seed:4d} {plan['status']}")
                continue
            report = simulate(plan).report
            hands = str(plan["hands"])
            if report["fault"] is not None:
                print(f"{name:15s} {hands:12s} {seed:4d} {plan['timing']['duration_s']:10.2f} fault: "
                      f"{report['fault']['kind']} at {report['fault']['at_s']:.2f} s")
                faults += 1
                continue
            ratios.append(report["cop_margin_ratio"])
            print(f"{name:15s} {hands:12s} {seed:4d} {plan['timing']['duration_s']:10.2f} "
                  f"{1000 * plan['min_margin_m']:13.1f} {1000 * report['min_cop_margin_m']:10.1f} "
                  f"{report['min_cop_margin_at_s']:6.2f} {report['cop_margin_ratio']:6.2f}", flush=True)
        if ratios or faults:
            summary.append((name, ratios, faults))
    print(f"\n{'scenario':15s} {'n':>2s} {'smallest':>8s} {'median':>7s} {f'>= {TARGET}':>8s} {'faulted':>7s}")
    for name, ratios, faults in summary:
        n = len(ratios) + faults  # a faulted run keeps nothing: it counts against the target
        smallest = f"{min(ratios):8.2f}" if ratios else f"{'-':>8s}"
        median = f"{statistics.median(ratios):7.2f}" if ratios else f"{'-':>7s}"
        print(f"{name:15s} {n:2d} {smallest} {median} {sum(r >= TARGET for r in ratios):4d}/{n} {faults:7d}")


if __name__ == "__main__":
    main()
