"""Test plans for the bridge, built with the planner's own code (tests may import it; the gate may not).

A plan stands in a solved stance and moves one or more joints with a cosine
profile (rest to rest, within the velocity and acceleration limits) at dt 5 ms.
Its com / margin_m / zmp fields are filled by the planner's kinematics, the way a
real plan is.
"""

from __future__ import annotations

import copy
from functools import lru_cache

import numpy as np

from schemas.plan import PLAN_SCHEMA, plan_sha256

DT = 0.005
G = 9.81


@lru_cache(maxsize=None)
def _robot_and_stance(robot_name: str, stance: str):
    from planner.robot.model import load_robot
    from planner.stability.stances import solve_stance

    robot = load_robot(robot_name)
    return robot, solve_stance(robot, stance)


def stance_state(robot_name: str = "hrp5p", stance: str = "upright") -> tuple[list[str], list[float], list[float]]:
    """(joint_names, q, base_pose) of a solved stance."""
    robot, st = _robot_and_stance(robot_name, stance)
    return list(robot.joint_names), st.q.tolist(), st.base_pose.tolist()


def cosine_profile(n_move: int, rest_before: int = 0, rest_after: int = 0) -> np.ndarray:
    """Progress 0 -> 1 over ``n_move`` steps (n_move + 1 points), rest to rest, with rest points before and after."""
    move = 0.5 * (1 - np.cos(np.pi * np.arange(n_move + 1) / n_move))
    return np.concatenate([np.zeros(rest_before), move, np.ones(rest_after)])


def build_plan(
    moves: dict[str, float] | None = None,
    *,
    duration_s: float = 1.5,
    rest_s: float = 0.05,
    robot_name: str = "hrp5p",
    stance: str = "upright",
    threshold_m: float = 0.03,
    mass_kg: float = 2.0,
    holding: str = "none",
    com_local: tuple[float, float, float] = (0.0, 0.0, 0.05),
) -> dict:
    """A solved plan moving ``moves`` (joint -> delta rad) with one cosine profile over ``duration_s``.

    ``holding`` other than "none": the object rides rigidly with that hand (its TCP), from the first point.
    """
    from planner.kinematics.batch import BatchKinematics

    robot, st = _robot_and_stance(robot_name, stance)
    moves = moves if moves is not None else {"RSP": -0.3}
    n_rest = int(round(rest_s / DT))
    s = cosine_profile(int(round(duration_s / DT)), n_rest, n_rest)
    Q = np.repeat(st.q[None], len(s), axis=0)
    for joint, delta in moves.items():
        Q[:, robot.joint_index(joint)] += s * delta
    bk = BatchKinematics(robot)
    side = {"left": "l_tcp", "right": "r_tcp", "both": "r_tcp"}.get(holding, "r_tcp")
    rcom, frames = bk.com_and_frames(st.base_pose, Q, [side])
    R, p = frames[side]
    offset = np.array([0.0, 0.0, 0.08])  # object frame 8 cm along the approach axis
    if holding == "none":
        table = np.array([0.45, -0.2, 0.75])
        obj_p = np.repeat(table[None], len(Q), axis=0)
        obj_R = np.repeat(np.eye(3)[None], len(Q), axis=0)
    else:
        obj_p = p + np.einsum("nij,j->ni", R, offset)
        obj_R = R
    poses = np.hstack([obj_p, _quat(obj_R)])
    ocom = obj_p + np.einsum("nij,j->ni", obj_R, np.array(com_local))
    if holding == "none":
        com = rcom
    else:
        com = (robot.total_mass * rcom + mass_kg * ocom) / (robot.total_mass + mass_kg)
    margin = st.polygon.margin(com[:, :2])
    acc = np.zeros((len(com), 2))
    acc[1:-1] = (com[2:, :2] - 2 * com[1:-1, :2] + com[:-2, :2]) / DT**2
    zmp = com[:, :2] - com[:, 2:3] / G * acc
    traj = [
        {"t": i * DT, "q": Q[i].tolist(), "holding": holding, "object_pose": poses[i].tolist(), "com": com[i].tolist(),
         "margin_m": float(margin[i]), "zmp": zmp[i].tolist()}
        for i in range(len(Q))
    ]
    res = st.result().model_dump()
    return {
        "schema": PLAN_SCHEMA, "status": "solved", "failure": None,
        "robot": {"name": robot.name, "urdf_sha256": robot.urdf_sha256, "joint_names": list(robot.joint_names)},
        "scenario": {"name": "bridge-test"},
        "stance": res,
        "support_polygon": st.polygon.vertices.tolist(),
        "object": {"name": "box", "mass_kg": mass_kg, "com_local": list(com_local), "start_pose": poses[0].tolist(),
                   "goal_pose": poses[-1].tolist()},
        "threshold_m": threshold_m, "hands": "right-right", "dt_s": DT, "trajectory": traj,
        "segments": [{"kind": "transit", "hand": "none", "first": 0, "last": len(traj) - 1}],
        "min_margin_m": float(margin.min()), "alternatives": [], "stats": {},
    }


def true_min_margin(plan: dict, oversample: int = 2) -> float:
    """The planner's view of the plan's smallest CoM margin over points and midpoints (linear q)."""
    from planner.kinematics.batch import BatchKinematics, quat_to_matrix
    from planner.stability.support_polygon import SupportPolygon

    robot, st = _robot_and_stance(plan["robot"]["name"], plan["stance"]["name"])
    Q = np.array([p["q"] for p in plan["trajectory"]])
    poses = np.array([p["object_pose"] for p in plan["trajectory"]])
    held = np.array([p["holding"] != "none" for p in plan["trajectory"]])
    f = np.arange(oversample) / oversample
    Qs = np.vstack([(Q[:-1, None] + f[None, :, None] * np.diff(Q, axis=0)[:, None]).reshape(-1, Q.shape[1]), Q[-1:]])
    Ps = np.vstack([(poses[:-1, None, :3] + f[None, :, None] * np.diff(poses[:, :3], axis=0)[:, None]).reshape(-1, 3), poses[-1:, :3]])
    Hs = np.concatenate([np.repeat(held[:-1], oversample), held[-1:]])
    Rs = quat_to_matrix(np.vstack([np.repeat(poses[:-1, 3:], oversample, axis=0), poses[-1:, 3:]]))
    rcom = BatchKinematics(robot).com(np.array(plan["stance"]["base_pose"]), Qs)
    ocom = Ps + np.einsum("nij,j->ni", Rs, np.array(plan["object"]["com_local"]))
    m = plan["object"]["mass_kg"] * Hs[:, None]
    com = (robot.total_mass * rcom + m * ocom) / (robot.total_mass + m)
    return float(SupportPolygon(st.polygon.vertices).margin(com[:, :2]).min())


def edited(plan: dict, fn) -> dict:
    """A deep copy of ``plan`` changed by ``fn(copy)``."""
    out = copy.deepcopy(plan)
    fn(out)
    return out


def _quat(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()  # [x, y, z, w]


__all__ = ["build_plan", "cosine_profile", "stance_state", "true_min_margin", "edited", "plan_sha256", "DT"]
