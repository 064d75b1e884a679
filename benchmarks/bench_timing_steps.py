"""Where the plan timing's time goes, step by step, in one process (no forked helper, so that every step's wall time
is its own): per scenario the plan's motion duration (the seed's alone), the search (the planning time less the
timing stage), then the quicker paths' steps (the replans, the task-space vias, the joint-space box vias, the full
shortening, the ranking by coarse TOPP-RA time, the corner easing) and the time parameterization's two timings (the
first gives the plan's smallest static margin for the reserve's cap, the second is the plan's; with no cap the only
one is the first: :meth:`planner.regrasp.timing.plan_timer.PlanTimer.time_plan`), each with its share of the search.
A step's time is counted once, where it is entered first (the easing's own estimated times are the easing's). Like
``bench_timing_stage.py`` it measures a second plan of each task (its survey cached) unless ``--first``;
``--repeats N`` prints the medians of N plans; ``--set KEY=VALUE`` changes a plan-timing setting as there. The
timing's steps are wrapped for the measurement only: the plans are the ones ``regrasp plan`` makes with
``parallel_motions`` off (the same plans, as its tests check). Times are this machine's.

    python benchmarks/bench_timing_steps.py
    python benchmarks/bench_timing_steps.py --set corner_easing_sweeps=2
    python benchmarks/bench_timing_steps.py --scenario drill-handover --repeats 3
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_timing_stage import settings_with  # noqa: E402  (this script's own directory)
from planner.jobs.plan_job import plan_scenario  # noqa: E402
from planner.regrasp.settings import PlannerSettings  # noqa: E402
from planner.regrasp.timing.plan_timer import PlanTimer  # noqa: E402
from planner.scene.scenarios import load_builtin  # noqa: E402
from planner.survey.cache import ENV_DIR  # noqa: E402

SCENARIOS = ("upright", "staggered", "crouched", "one-legged", "drill-handover")
#: the timed steps: the timer's method and the column it counts into
STEPS = (("_replans", "replans"), ("_via_paths", "vias"), ("_box_via_paths", "box vias"),
         ("_shortened", "shortening"), ("_estimated_time", "ranking"), ("_with_eased", "easing"),
         ("_time_runs", "timings"))
COLUMNS = ("search", "replans", "vias", "box vias", "shortening", "ranking", "easing", "first timing",
           "second timing")


class StepClock:
    """Wall time per step of the timing, each counted where it is entered first (the outermost timed step)."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self.active: str | None = None
        self.timings = 0  # the _time_runs calls of this plan so far

    def wrap(self, method, label: str):
        @functools.wraps(method)
        def timed(*args, **kwargs):
            if self.active is not None:
                return method(*args, **kwargs)
            name = label
            if label == "timings":
                self.timings += 1
                name = "first timing" if self.timings == 1 else "second timing"
            self.active, started = name, time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                self.times[name] = self.times.get(name, 0.0) + time.perf_counter() - started
                self.active = None
        return timed

    def reset(self) -> None:
        self.times, self.timings = {}, 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--first", action="store_true", help="the first plan of each task, its survey computed in it")
    ap.add_argument("--repeats", type=int, default=1, help="plans measured per scenario (their median times)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a plan-timing setting, its value as JSON (e.g. corner_easing_sweeps=2)")
    args = ap.parse_args()
    clock = StepClock()
    for method, label in STEPS:
        setattr(PlanTimer, method, clock.wrap(getattr(PlanTimer, method), label))
    update, settings = settings_with(args.set, PlannerSettings().model_copy(update={"parallel_motions": False}))
    print(f"one process; settings changed: {update or 'none'}; seconds (share of the search); "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'scenario':15s} {'motion s':>8s} {'plan s':>7s} " + " ".join(f"{c:>13s}" for c in COLUMNS))
    for name in args.scenario:
        scenario = load_builtin(name)
        if not args.first:
            plan_scenario(scenario, settings=settings)
        rows = []
        for _ in range(args.repeats):
            if args.first:
                os.environ[ENV_DIR] = tempfile.mkdtemp(prefix="bench-timing-steps-")
            clock.reset()
            plan = plan_scenario(scenario, settings=settings)
            if plan["status"] != "solved":
                break
            row = dict(clock.times)
            row["search"] = plan["stats"]["time_s"] - plan["stats"]["timing"]["time_s"]
            row["plan"] = plan["stats"]["time_s"]
            rows.append(row)
        if len(rows) < args.repeats:
            print(f"{name:15s} {plan['status']}")
            continue
        med = {c: statistics.median(r.get(c, 0.0) for r in rows) for c in (*COLUMNS, "plan")}
        cells = [f"{med['search']:6.2f}" + " " * 7] + [f"{med[c]:6.2f} ({100 * med[c] / med['search']:3.0f}%)"
                                                     for c in COLUMNS[1:]]
        print(f"{name:15s} {plan['timing']['duration_s']:8.2f} {med['plan']:7.2f} " + " ".join(f"{c:>13s}" for c in cells))


if __name__ == "__main__":
    main()
