"""Descriptive figures of a robot: mass, height, limits, stances (``regrasp robot info``)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from planner.robot.model import RobotModel
from planner.robot.urdf_geometry import collision_primitives
from planner.stability.effort import effort_limits
from planner.stability.stances import BUILTIN_STANCES, StanceError, solve_stance


def standing_height(robot: RobotModel) -> float:
    """Height of the highest collision point with straight legs, soles flat on the ground."""
    model = robot.pin_model
    data = robot.create_data()
    q = np.clip(np.zeros(robot.nq), robot.lower, robot.upper)
    base = np.array([0, 0, 0, 0, 0, 0, 1.0])
    pin.framesForwardKinematics(model, data, robot.to_pin_q(base, q))
    sole_z = min(data.oMf[robot.frame_id(f.frame)].translation[2] for f in robot.spec.feet.values())
    top = -np.inf
    for prim in collision_primitives(robot.urdf_path):
        M = data.oMf[model.getFrameId(prim.link)]
        pts = prim.local_points() @ M.rotation.T + M.translation
        top = max(top, float(pts[:, 2].max()))
    return top - sole_z


def robot_info(robot: RobotModel) -> dict[str, Any]:
    stances: list[dict[str, Any]] = []
    for name in BUILTIN_STANCES:
        try:
            st = solve_stance(robot, name)
            stances.append({"name": name, "base_pose": st.base_pose.tolist(), "q": st.q.tolist(),
                            "com": st.robot_com.tolist(), "margin_m": st.margin,
                            "support_polygon": st.polygon.vertices.tolist()})
        except StanceError as exc:
            stances.append({"name": name, "error": str(exc)})
    return {
        "name": robot.name,
        "description": robot.spec.description,
        "urdf": str(robot.urdf_path),
        "urdf_sha256": robot.urdf_sha256,
        "total_mass_kg": robot.total_mass,
        "height_m": standing_height(robot),
        "dof": robot.nq,
        "joint_names": list(robot.joint_names),
        "position_limits": {n: [float(lo), float(hi)] for n, lo, hi in zip(robot.joint_names, robot.lower, robot.upper)},
        "velocity_limits": {n: float(v) for n, v in zip(robot.joint_names, robot.velocity_limit)},
        "acceleration_limits": {n: float(a) for n, a in zip(robot.joint_names, robot.acceleration_limit)},
        "effort_limits": effort_limits(robot),
        "grip": robot.spec.grip.model_dump() if robot.spec.grip is not None else None,
        "limit_sources": robot.spec.limit_sources,
        "frames": {"soles": robot.spec.sole_frames(), "tcps": robot.spec.tcp_frames()},
        "stances": stances,
    }
