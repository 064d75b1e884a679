"""Motion benchmark: IK solves/s (one by one and batched), state evaluations/s, T-RRT rounds/s, exploration states/s.

Run: ``python benchmarks/bench_motion.py [--states N] [--no-collision]``. Short by design
(a few seconds); figures depend on the machine's load. The survey's target is 4
configurations x 20,000 states in <= 10 s on 2 cores, i.e. ~8,000 states/s per core
with collision checks.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from planner.kinematics.batch import BatchKinematics
from planner.motion.ik import IkSolver
from planner.motion.ik_batch import BatchIk
from planner.motion.trrt import TrrtSettings, plan_motion
from planner.robot.model import load_robot
from planner.stability.evaluator import HoldSpec, StateEvaluator
from planner.stability.stances import solve_stance
from planner.survey.counting import ExploreLeg, explore_counted

COM_LOCAL = np.array([0.15, 0.08, 0.15])


def _timeit(fn, repeat: int) -> float:
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t0) / repeat


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--states", type=int, default=20_000, help="states per exploration run")
    ap.add_argument("--no-collision", action="store_true", help="skip the runs with the collision checker")
    args = ap.parse_args()
    from planner.warmup import warm_up

    warm_up()  # steady state: the compiled kernels loaded (or compiled, on a machine's first run)

    robot = load_robot("hrp5p")
    stance = solve_stance(robot, "upright")
    ev = StateEvaluator(robot, stance, 0.06, 8.0, COM_LOCAL)
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, -0.1]
    hold = HoldSpec("right", T)
    act = np.r_[robot.waist_indices(), robot.arm_indices("right")]
    rng = np.random.default_rng(0)

    # IK
    ik = IkSolver(robot, stance)
    targets = []
    for _ in range(60):
        q = stance.q.copy()
        q[act] = np.clip(stance.q[act] + rng.normal(0, 0.5, len(act)), robot.lower[act], robot.upper[act])
        targets.append(ik.tcp_pose(q, "right"))
    t0 = time.perf_counter()
    ok = sum(ik.solve_arm("right", Tt, stance.q, rng).ok for Tt in targets)
    dt = (time.perf_counter() - t0) / len(targets)
    print(f"IK waist+arm: {1 / dt:8.0f} solves/s ({dt * 1e6:.0f} us/solve, {ok}/{len(targets)} reached)")
    both = []
    act2 = ik.active_indices(["left", "right"])
    for _ in range(20):
        q = stance.q.copy()
        q[act2] = np.clip(stance.q[act2] + rng.normal(0, 0.3, len(act2)), robot.lower[act2], robot.upper[act2])
        both.append((ik.tcp_pose(q, "left"), ik.tcp_pose(q, "right")))
    t0 = time.perf_counter()
    ok = sum(ik.solve_both(a, b, stance.q, rng).ok for a, b in both)
    dt = (time.perf_counter() - t0) / len(both)
    print(f"IK waist+2 arms: {1 / dt:5.0f} solves/s ({dt * 1e6:.0f} us/solve, {ok}/{len(both)} reached)")

    # Batched IK (the search's grasp probes): arm alone, one descent per target, all advanced together
    arm = IkSolver(robot, stance, ik.settings.model_copy(update={"use_waist": False, "restarts": 0}))
    batch = BatchIk(robot, BatchKinematics(robot), arm.settings)
    arm_act = robot.arm_indices("right")
    for n in (100, 1000):
        Q = np.repeat(stance.q[None], n, axis=0)
        Q[:, arm_act] = np.clip(stance.q[arm_act] + rng.normal(0, 0.5, (n, len(arm_act))), robot.lower[arm_act], robot.upper[arm_act])
        T_batch = np.array([arm.tcp_pose(q, "right") for q in Q])
        t0 = time.perf_counter()
        res = batch.solve("right", T_batch, stance.base_pose, stance.q, stance.q)
        dt = time.perf_counter() - t0
        t0 = time.perf_counter()
        one = sum(arm.solve_arm("right", Tt, stance.q, rng).ok for Tt in T_batch[:100])
        dt1 = (time.perf_counter() - t0) / 100
        print(f"IK arm alone, batched N={n:5d}: {n / dt:7.0f} solves/s ({dt / n * 1e6:.0f} us/solve, {res.ok.sum()}/{n} reached); "
              f"one by one {1 / dt1:5.0f} solves/s ({one}/100 reached)")

    # State evaluation
    for n in (1, 64, 1024, 8192):
        Q = np.repeat(stance.q[None], n, axis=0)
        Q[:, act] = rng.uniform(robot.lower[act], robot.upper[act], (n, len(act)))
        if n == 1:
            dt = _timeit(lambda: ev.evaluate_one(Q[0], hold), 500)
        else:
            dt = _timeit(lambda: ev.evaluate(Q, hold, active=act), max(3, 20000 // n))
        print(f"evaluate N={n:5d}: {n / dt:9.0f} states/s ({dt / n * 1e6:.2f} us/state)")

    # T-RRT planning rounds (stability only, an obstacle on the straight line)
    start = stance.q.copy()
    goal = start.copy()
    goal[act] = np.clip([0.1, 0.0, 0.5, 0.2, -0.6, -0.5, 0.3, -1.2, 0.3, 0.2, 0.1, 0.0], robot.lower[act], robot.upper[act])
    ev3 = StateEvaluator(robot, stance, 0.03, 3.0, COM_LOCAL)
    mid = 0.5 * (start[act] + goal[act])

    def validity(Q):
        b = ev3.evaluate(Q, hold, active=act)
        return b.stable & (np.linalg.norm(Q[:, act] - mid, axis=1) >= 0.4), b.margin

    rounds = states = 0
    t0 = time.perf_counter()
    for seed in range(10):
        res = plan_motion(start, goal, act, validity, robot.lower, robot.upper, np.random.default_rng(seed))
        rounds += res.stats["rounds"]
        states += res.stats["states_checked"]
    dt = time.perf_counter() - t0
    print(f"T-RRT plan (10 runs): {dt / 10 * 1e3:.1f} ms/plan, {rounds / dt:.0f} rounds/s (x{TrrtSettings().batch_size} extensions), {states / dt:.0f} states/s")

    # Exploration without collision
    legs = [ExploreLeg(start, goal, hold, act)]
    ev = ev3  # a task whose pick and place states are stable (the survey's case)
    t0 = time.perf_counter()
    ex = explore_counted(legs, ev, np.random.default_rng(1), budget=args.states)
    dt = time.perf_counter() - t0
    print(f"counted exploration, no collision: {args.states / dt:.0f} sampled poses/s ({args.states} in {dt:.2f} s; "
          f"C={ex.n_stable} U={ex.n_unstable}, solved={ex.solved})")

    if args.no_collision:
        return
    try:
        from planner.scene.bodies import EnvBox
        from planner.scene.collision import CollisionWorld
        from planner.scene.objects import build_object
        from schemas.scenario import ObjectDef
    except ImportError as exc:  # the collision checker is another area's work
        print(f"collision checker unavailable: {exc}")
        return
    table = np.eye(4)
    table[:3, 3] = [0.9, 0.0, 0.25]  # a table in front of the robot, top at 0.50 m
    obj = build_object(ObjectDef(shape="box", size=[0.06, 0.10, 0.20], mass_kg=3.0))
    names = [robot.joint_names[i] for i in act]
    world = CollisionWorld(robot, [EnvBox("table", table, (0.5, 1.2, 0.5))], obj, moving_joints=names,
                           reference_postures=[(stance.base_pose, stance.q)])
    calls = {"n": 0, "t": 0.0}

    def collision_free(Q):
        t = time.perf_counter()
        out = ~world.check_batch(stance.base_pose, Q, held=[("right", T)]).collides
        calls["n"] += len(Q)
        calls["t"] += time.perf_counter() - t
        return out

    t0 = time.perf_counter()
    legs = [ExploreLeg(start, goal, hold, act, collision_free)]
    ex = explore_counted(legs, ev, np.random.default_rng(1), budget=args.states)
    dt = time.perf_counter() - t0
    print(
        f"counted exploration, with collision: {args.states / dt:.0f} sampled poses/s ({args.states} in {dt:.2f} s; "
        f"collision {calls['n'] / max(calls['t'], 1e-9):.0f} checks/s = {calls['t'] / dt:.0%} of the time)"
    )


if __name__ == "__main__":
    main()
