"""CoM + margin evaluations per second for hrp5p: one state per call, and batched.

Targets (one core): <= 20 us per single state; >= 200,000 states/s batched.
Run: python benchmarks/bench_stability.py
"""

from __future__ import annotations

import time

import numpy as np

from planner.kinematics.batch import BatchKinematics
from planner.robot.model import load_robot
from planner.stability.robot_com import robot_com as center_of_mass
from planner.stability.stances import solve_stance


def main() -> None:
    from planner.warmup import warm_up

    warm_up()  # steady state: the compiled kernels loaded (or compiled, on a machine's first run)
    robot = load_robot("hrp5p")
    stance = solve_stance(robot, "upright")
    poly = stance.polygon
    rng = np.random.default_rng(0)
    # Upper-body motions with the stance's legs, as the planner and survey evaluate them.
    Q = np.repeat(stance.q[None], 50_000, axis=0)
    upper = np.setdiff1d(np.arange(robot.nq), stance.leg_indices)
    Q[:, upper] = rng.uniform(robot.lower[upper], robot.upper[upper], size=(len(Q), len(upper)))

    data = robot.create_data()
    n_single = 20_000
    t0 = time.perf_counter()
    for i in range(n_single):
        c = center_of_mass(robot, data, stance.base_pose, Q[i])
        poly.margin_one(c[0], c[1])
    single_us = (time.perf_counter() - t0) / n_single * 1e6

    bk = BatchKinematics(robot)
    rates = {}
    for batch in (1_000, 10_000, 50_000):
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            com = bk.com(stance.base_pose, Q[:batch])
            poly.margin(com[:, :2])
            best = min(best, time.perf_counter() - t0)
        rates[batch] = batch / best
    print("CoM + margin, hrp5p (37 DoF), upright stance polygon")
    print(f"  single state (pinocchio centerOfMass + margin): {single_us:.1f} us/state  (target <= 20 us)")
    for batch, rate in rates.items():
        print(f"  batched (compiled), batch {batch:>6}: {rate:,.0f} states/s  (target >= 200,000)")


if __name__ == "__main__":
    main()
