"""Stable key postures: what one costs, how often one is found, and what they change in a plan.

Run: ``python benchmarks/bench_stable_posture.py [--scenario crouched] [--grasps 80] [--repeats 3]``.

1. For the grasps of the task's start and goal placements whose IK posture fails the planning
   threshold (the hand's own IK, as the planner's probes solve it), the time of
   ``Task.stable_posture`` per posture found and per refusal, and how many are found.
2. The task planned in each hand configuration with stable postures on and off (medians of
   ``--repeats`` warm runs, alternated): status, minimum margin, nodes removed for the margin,
   planning time.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from planner.blas_threads import one_blas_thread
from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.regrasp.settings import PlannerSettings
from planner.regrasp.search_data import SearchData, solve_ik, stable_posture
from planner.regrasp.task import Task
from planner.scene.scenarios import resolve_scenario
from planner.stability.evaluator import HoldSpec
from planner.transforms import inverse

HANDS = ("left-left", "right-right", "left-right", "right-left")


def posture_costs(scenario_name: str, grasps: int) -> None:
    task = Task(resolve_scenario(scenario_name), PlannerSettings(limits=False))
    found, refused = [], []
    for side, placement in (("right", task.start_id), ("left", task.goal_id)):
        T_obj = task.placements[placement]
        for k, g in enumerate(task.grasps[side][:grasps]):
            q = solve_ik(task, SearchData(task), side, T_obj @ g.T_obj_tcp, task.home, np.random.default_rng(k))
            if q is None:
                continue
            q[task.jaw[side]] = g.jaw_value
            hold = HoldSpec(side, inverse(T_obj) @ task.tcp(q, side))
            if task.evaluator.evaluate_one(q, hold).stable:
                continue
            t0 = time.perf_counter()
            out = stable_posture(task, SearchData(task), q, (side,), T_obj)
            (found if out is not None else refused).append(time.perf_counter() - t0)
    n = len(found) + len(refused)
    print(f"{scenario_name}: {n} IK postures below the planning threshold at the start and goal grasps; "
          f"stable posture found for {len(found)} ({100 * len(found) / max(n, 1):.0f} %)")
    if found:
        print(f"  found:   median {1000 * statistics.median(found):.2f} ms, max {1000 * max(found):.2f} ms")
    if refused:
        print(f"  refused: median {1000 * statistics.median(refused):.2f} ms, max {1000 * max(refused):.2f} ms")


def plans(scenario_name: str, repeats: int) -> None:
    sc = resolve_scenario(scenario_name)
    print(f"\n{scenario_name}, planned without limits, medians of {repeats} warm runs (on / off alternated):")
    print(f"{'hands':<12} {'stable postures':<16} {'status':<28} {'min margin':>11} {'margin removals':>16} {'time s':>8}")
    for hands in HANDS:
        for on in (True, False):
            settings = PlannerSettings(limits=False, stable_postures=on)
            plan_scenario(sc, PlanOptions(hands=hands, limits=False), settings=settings)  # warm: grasp cache, kernels
        times: dict[bool, list[float]] = {True: [], False: []}
        docs: dict[bool, dict] = {}
        for _ in range(repeats):
            for on in (True, False):
                settings = PlannerSettings(limits=False, stable_postures=on)
                t0 = time.perf_counter()
                docs[on] = plan_scenario(sc, PlanOptions(hands=hands, limits=False), settings=settings)
                times[on].append(time.perf_counter() - t0)
        for on in (True, False):
            d = docs[on]
            status = d["status"] if d["status"] == "solved" else f"{d['status']} ({d['failure']['code']})"
            counts = d["stats"].get("failures") if d["status"] == "solved" else d["failure"].get("counts") or {}
            margin = "-" if d.get("min_margin_m") is None else f"{1000 * d['min_margin_m']:.1f} mm"
            print(f"{hands:<12} {'on' if on else 'off':<16} {status:<28} {margin:>11} {int(counts.get('com_margin', 0)):>16} "
                  f"{statistics.median(times[on]):>8.2f}")


@one_blas_thread  # as the CLI's plans run (planner/blas_threads.py)
def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenario", default="crouched")
    ap.add_argument("--grasps", type=int, default=80, help="grasps per hand tried at the start and goal placements")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from planner.warmup import warm_up

    warm_up()
    posture_costs(args.scenario, args.grasps)
    plans(args.scenario, args.repeats)


if __name__ == "__main__":
    main()
