"""The system CoM of robot plus held object: the paper's equation 1, in one place.

``G = (M G_robot + m G_object) / (M + m)``, with ``G_robot`` the robot's CoM (pinocchio or the
batched kinematics) and ``G_object`` the held object's CoM in the world (its pose applied to its
local CoM). An object resting on a table is not part of it. Every evaluation of a state's
stability (the planner's, the survey's) goes through these two functions.
"""

from __future__ import annotations

import numpy as np


def object_com_world(object_pose: np.ndarray, com_local: np.ndarray) -> np.ndarray:
    """The object's CoM in the world from its pose(s) (4, 4) or (N, 4, 4) and its CoM in the object frame."""
    return object_pose[..., :3, :3] @ com_local + object_pose[..., :3, 3]


def system_com(robot_com: np.ndarray, robot_mass: float, object_com: np.ndarray | None, object_mass: float) -> np.ndarray:
    """The paper's equation 1: (M G_robot + m G_object) / (M + m); batched over leading axes.

    Pass ``object_com = None`` or ``object_mass = 0`` when nothing is held.
    """
    if object_com is None or object_mass == 0.0:
        return np.asarray(robot_com, dtype=float)
    return (robot_mass * np.asarray(robot_com) + object_mass * np.asarray(object_com)) / (robot_mass + object_mass)


def system_com_xy_fixed_object(robot_com_xy: np.ndarray, robot_jacobian_xy: np.ndarray, robot_mass: float,
                               object_com_xy: np.ndarray | None, object_mass: float) -> tuple[np.ndarray, np.ndarray]:
    """Equation 1 on the ground plane with the held object's CoM fixed (the hands hold still): the system
    CoM (2,) and its Jacobian from the robot's (2, k); ``object_com_xy = None`` when nothing is held."""
    share = robot_mass / (robot_mass + object_mass)
    held = np.zeros(2) if object_com_xy is None or object_mass == 0.0 else np.asarray(object_com_xy)[:2]
    return share * robot_com_xy[:2] + (1.0 - share) * held, share * robot_jacobian_xy
