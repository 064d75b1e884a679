"""Cost of the effort and grip checks: batched per state against the CoM check alone, and planning time
with the limits against without on the paper's scenarios.

Targets: the torque + grip check at most 2x the CoM check per state (batches as the planner checks them);
planning with the limits at most 1.3x the time without.
Run: python benchmarks/bench_limits.py [--plans] [--scenarios upright,crouched]

The planning ratio of two medians moves by +-15 % on a shared machine, so the benchmark also times the limit
checks themselves inside each plan (the only work the limits add: the same states are searched either way,
as the plans' counters show) and prints (time without + the checks' time) / time without.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from planner.robot.model import load_robot
from planner.stability.effort import EffortEvaluator
from planner.stability.evaluator import HoldSpec, StateEvaluator
from planner.stability.stances import solve_stance


def per_state(robot_name: str, batch: int, repeats: int = 200) -> tuple[float, float]:
    """(us per state of the CoM check, us per state of the torque + grip check), batches of ``batch``."""
    robot = load_robot(robot_name)
    stance = solve_stance(robot, "upright")
    ev = StateEvaluator(robot, stance, 0.06, 8.0, np.array([0.0, 0.0, 0.05]))
    lim = EffortEvaluator(robot, stance, 8.0, np.array([0.0, 0.0, 0.05]))
    rng = np.random.default_rng(0)
    active = np.concatenate([robot.waist_indices(), robot.arm_indices("right")])
    Q = np.repeat(stance.q[None], batch, axis=0)
    Q[:, active] = rng.uniform(robot.lower[active], robot.upper[active], (batch, active.size))
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 0.08]
    hold = HoldSpec("right", T)
    for _ in range(3):  # warm: compiled kernels, the reduced tree
        ev.evaluate(Q, hold, active=active)
        lim.evaluate(Q, "right", T_tcp_obj=hold.T_tcp_obj)
    best_com = best_lim = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(repeats):
            ev.evaluate(Q, hold, active=active)
        best_com = min(best_com, time.perf_counter() - t0)
        t0 = time.perf_counter()
        for _ in range(repeats):
            lim.evaluate(Q, "right", T_tcp_obj=hold.T_tcp_obj)
        best_lim = min(best_lim, time.perf_counter() - t0)
    n = repeats * batch
    return best_com / n * 1e6, best_lim / n * 1e6


#: Fixed hands per scenario (a plan with ``hands: auto`` would first need the task's survey).
PLAN_HANDS = {"upright": "left-left", "staggered": "left-left", "crouched": "right-right", "one-legged": "left-left",
              "talos-upright": "right-right", "g1-upright": "right-right", "drill-handover": "right-left",
              "drill-upright": "right-right"}


class _LimitClock:
    """Wall time spent in the state checker's limit checks (the only work the limits add to a plan), by
    wrapping :meth:`StateChecker._limit_causes` while the benchmark runs."""

    def __init__(self) -> None:
        from planner.regrasp.state_checker import StateChecker

        self.seconds = 0.0
        original = StateChecker._limit_causes

        def timed(checker, *args, **kwargs):
            t0 = time.perf_counter()
            try:
                return original(checker, *args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - t0

        StateChecker._limit_causes = timed


def plan_times(scenario: str, repeats: int, clock: _LimitClock) -> tuple[float, float, float, str, str]:
    """Median planning times without and with the limits, run alternately ``repeats`` times each, the median
    time of the limit checks within a plan, and the statuses (failure codes) of the last runs."""
    import statistics

    from planner.jobs.plan_job import PlanOptions, plan_scenario
    from planner.scene.scenarios import load_builtin

    sc = load_builtin(scenario)
    times: dict[bool, list[float]] = {False: [], True: []}
    checks: list[float] = []
    status = {}
    for _ in range(repeats):
        for limits in (False, True):
            clock.seconds = 0.0
            t0 = time.perf_counter()
            doc = plan_scenario(sc, PlanOptions(limits=limits, hands=PLAN_HANDS.get(scenario)))
            times[limits].append(time.perf_counter() - t0)
            if limits:
                checks.append(clock.seconds)
            status[limits] = doc["status"] + (f" {doc['failure']['code']}" if doc.get("failure") else "")
    return (statistics.median(times[False]), statistics.median(times[True]), statistics.median(checks), status[False],
            status[True])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plans", action="store_true", help="also time planning with and without limits")
    ap.add_argument("--scenarios", default="upright,staggered,crouched,one-legged")
    ap.add_argument("--robots", default="hrp5p")
    ap.add_argument("--repeats", type=int, default=3, help="plans per scenario and setting, run alternately")
    args = ap.parse_args()
    from planner.warmup import warm_up

    warm_up()
    for robot in args.robots.split(","):
        for batch in (40, 400):
            com_us, lim_us = per_state(robot, batch)
            print(f"{robot} batch {batch:4d}: CoM check {com_us:6.2f} us/state, torque + grip {lim_us:6.2f} us/state, "
                  f"ratio {lim_us / com_us:.2f} (target <= 2)")
    if args.plans:
        clock = _LimitClock()
        for name in args.scenarios.split(","):
            off, on, checks, s_off, s_on = plan_times(name, args.repeats, clock)
            print(f"plan {name:14s} ({PLAN_HANDS.get(name)}): without limits {off:6.2f} s ({s_off}), with {on:6.2f} s "
                  f"({s_on}), ratio {on / off:.2f} (medians of {args.repeats}; target <= 1.3); the limit checks take "
                  f"{checks:.3f} s of a plan with them: (without + checks) / without = {(off + checks) / off:.2f}")


if __name__ == "__main__":
    main()
