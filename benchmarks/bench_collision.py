"""Benchmark of the planner geometry: collision checks per second, grasp planning cold/warm.

Run: python benchmarks/bench_collision.py [--states N] [--quick]
Prints CPU time per state (process time, so other load on the machine distorts it less)
for batches of configurations, with and without the forward kinematics, then the grasp,
placement and handover times per built-in object.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from planner.grasping.grasps import plan_grasps
from planner.grasping.handover import handover_poses
from planner.robot.model import load_robot
from planner.scene.bodies import environment_boxes
from planner.scene.collision import CollisionWorld
from planner.scene.hand import hand_geometry
from planner.scene.objects import build_object
from planner.scene.placements import instantiate_placements, reference_poses
from planner.scene.scenarios import builtin_names, load_builtin
from planner.stability.stances import solve_stance
from planner.transforms import pose7_to_matrix


def _configs(robot, stance, n: int, spread: float, rng: np.random.Generator) -> np.ndarray:
    """Waist + arm configurations: a blend of the stance posture and uniform samples."""
    idx = np.concatenate([robot.arm_indices("left"), robot.arm_indices("right"), robot.waist_indices()])
    Q = np.repeat(stance.q[None], n, axis=0)
    U = rng.uniform(robot.lower[idx], robot.upper[idx], (n, idx.size))
    Q[:, idx] = spread * U + (1 - spread) * stance.q[idx]
    return Q


def bench_checks(states: int) -> None:
    robot = load_robot("hrp5p")
    sc = load_builtin("upright")
    st = solve_stance(robot, sc.stance)
    obj = build_object(sc.object)
    T_start = pose7_to_matrix(sc.start_pose)
    moving = list(robot.spec.waist) + [j for a in robot.spec.arms.values() for j in (*a.chain, a.gripper.joint)]
    rng = np.random.default_rng(0)
    print("collision checks, scenario 'upright' (robot 25 shapes, table, carrier 6 boxes), CPU us per state")
    print(f"{'world':10s} {'configs':12s} {'batch':>6s} {'check':>9s} {'FK+check':>9s} {'checks/s':>9s} {'colliding':>9s}")
    for label, mj in (("full", None), ("waist+arms", moving)):
        world = CollisionWorld.from_scenario(robot, sc, obj, reference_postures=[(st.base_pose, st.q)], moving_joints=mj)
        for spread_label, spread in (("near stance", 0.05), ("uniform", 1.0)):
            Q = _configs(robot, st, states, spread, rng)
            for batch in (1, 10, 100, 1000):
                n = min(states, max(batch, 200 if batch == 1 else states))
                n -= n % batch
                t_chk = t_all = 0.0
                hits = 0
                for s in range(0, n, batch):
                    qb = Q[s:s + batch]
                    t0 = time.process_time()
                    Rs, ps = world.kin.forward(st.base_pose, qb)
                    t1 = time.process_time()
                    res = world.check_forward(Rs, ps, free_object_pose=T_start)
                    t2 = time.process_time()
                    t_chk += t2 - t1
                    t_all += t2 - t0
                    hits += int(res.collides.sum())
                per = t_chk / n * 1e6
                print(f"{label:10s} {spread_label:12s} {batch:6d} {per:9.1f} {t_all / n * 1e6:9.1f} {1e6 / per:9.0f} {hits / n:9.2f}")


def bench_grasps() -> None:
    robot = load_robot("hrp5p")
    print("\ngrasps / placements / handover per built-in object (wall s)")
    print(f"{'scenario':15s} {'object':8s} {'grasps':>6s} {'cold':>7s} {'warm':>7s} {'refs':>4s} {'places':>6s} {'t':>6s} {'handover':>8s} {'t':>6s}")
    seen = set()
    with tempfile.TemporaryDirectory() as cache:
        for name in builtin_names():
            sc = load_builtin(name)
            obj = build_object(sc.object)
            if obj.content_hash in seen:
                continue
            seen.add(obj.content_hash)
            cold = plan_grasps(obj, robot, "right", cache_directory=cache)
            warm = plan_grasps(obj, robot, "right", cache_directory=cache)
            t0 = time.perf_counter()
            refs = reference_poses(obj)
            tables = environment_boxes(sc)[: len(sc.tables)]
            places = instantiate_placements(obj, tables, pose7_to_matrix(sc.start_pose), pose7_to_matrix(sc.goal_pose), refs=refs)
            t_pl = time.perf_counter() - t0
            left = plan_grasps(obj, robot, "left", cache_directory=cache)
            st = solve_stance(robot, sc.stance)
            t0 = time.perf_counter()
            hp = handover_poses(obj, warm, left, hand_geometry(robot, "right"), hand_geometry(robot, "left"), st.base_pose[:3])
            t_ho = time.perf_counter() - t0
            print(f"{name:15s} {obj.name:8s} {len(cold):6d} {cold.seconds:7.3f} {warm.seconds:7.4f} {len(refs):4d} {len(places):6d} "
                  f"{t_pl:6.3f} {len(hp):8d} {t_ho:6.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--states", type=int, default=2000)
    ap.add_argument("--quick", action="store_true", help="fewer states")
    args = ap.parse_args()
    bench_checks(300 if args.quick else args.states)
    bench_grasps()


if __name__ == "__main__":
    main()
