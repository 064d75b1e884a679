"""What the plan timing adds to a plan's planning time, per scenario, as `regrasp plan` runs it.

Plans each scenario twice with the same seed and reports the second plan (its survey, for ``hands: auto``, read
from the cache the first one filled, so its planning time is the shortest a user sees). Per scenario: the motion
duration, the planning time (``stats.time_s``), the timing stage (``stats.timing.time_s``) and what it adds to the
rest of the planning time (stage / (planning - stage)), and of it the quicker paths (``quicker_paths_time_s``:
replans, vias, shortcuts, the ranking) and the rest, the time parameterization and its checks, with what it adds to
everything else. ``--set KEY=VALUE`` (repeatable) changes one
plan-timing setting (:class:`planner.regrasp.timing.settings.PlanTimingSettings`) for a before/after comparison run
back to back; the trajectory's hash then tells whether the plan changed. ``--first`` reports instead the first plan
of each task, its survey computed in the plan (an empty, temporary survey cache): what a new task's plan takes.
``--repeats N`` plans N times more (each ``--first`` plan with its own empty cache) and prints the medians of the
times, the percentages from those medians. Times are this machine's; the durations and hashes depend on the seed
only.

    python benchmarks/bench_timing_stage.py
    python benchmarks/bench_timing_stage.py --set path_check_rad=0.005
    python benchmarks/bench_timing_stage.py --first
    python benchmarks/bench_timing_stage.py --repeats 5
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import tempfile

from planner.jobs.plan_job import plan_scenario
from planner.regrasp.settings import PlannerSettings
from planner.scene.scenarios import load_builtin
from planner.survey.cache import ENV_DIR
from schemas.plan import canonical_json

SCENARIOS = ("upright", "staggered", "crouched", "one-legged", "drill-handover")


def settings_with(items: list[str], base: PlannerSettings | None = None) -> tuple[dict, PlannerSettings]:
    """The plan-timing settings ``KEY=VALUE`` items change (each value JSON) and the planner settings with them."""
    update = {}
    for item in items:
        key, _, value = item.partition("=")
        update[key] = json.loads(value)
    base = PlannerSettings() if base is None else base
    # validated, so that a nested setting (vias={"keep": 0}) becomes its model
    timing = type(base.plan_timing).model_validate({**base.plan_timing.model_dump(), **update})
    return update, base.model_copy(update={"plan_timing": timing})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a plan-timing setting, its value as JSON (e.g. path_check_rad=0.005)")
    ap.add_argument("--first", action="store_true", help="the first plan of each task, its survey computed in it")
    ap.add_argument("--repeats", type=int, default=1, help="plans measured per scenario (their median times)")
    args = ap.parse_args()
    update, settings = settings_with(args.set)
    print(f"settings changed: {update or 'none'}; load average {os.getloadavg()[0]:.1f}")
    print(f"{'scenario':15s} {'duration s':>10s} {'planning s':>10s} {'timing s':>9s} {'adds':>6s} "
          f"{'quicker s':>9s} {'param. s':>8s} {'adds':>6s}  trajectory")
    for name in args.scenario:
        scenario = load_builtin(name)
        if not args.first:  # the plans measured read the survey this one computes or finds cached
            plan_scenario(scenario, settings=settings)
        measured = []
        for _ in range(args.repeats):
            if args.first:
                os.environ[ENV_DIR] = tempfile.mkdtemp(prefix="bench-timing-stage-")
            measured.append(plan_scenario(scenario, settings=settings))
        plan = measured[-1]
        if plan["status"] != "solved":
            print(f"{name:15s} {plan['status']}")
            continue
        total = statistics.median(p["stats"]["time_s"] for p in measured)
        stage = statistics.median(p["stats"]["timing"]["time_s"] for p in measured)
        quicker = statistics.median(p["stats"]["timing"]["quicker_paths_time_s"] for p in measured)
        param = statistics.median(p["stats"]["timing"]["time_s"] - p["stats"]["timing"]["quicker_paths_time_s"]
                                  for p in measured)
        digests = {hashlib.sha256(canonical_json(p["trajectory"])).hexdigest()[:12] for p in measured}  # the plan's own form
        print(f"{name:15s} {plan['timing']['duration_s']:10.2f} {total:10.2f} {stage:9.2f} "
              f"{100 * stage / (total - stage):5.0f}% {quicker:9.2f} {param:8.2f} {100 * param / (total - param):5.0f}%  "
              f"{' '.join(sorted(digests))}")


if __name__ == "__main__":
    main()
