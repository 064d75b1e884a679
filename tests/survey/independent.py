"""An independent look at stored survey states: the URDF in pinocchio, the polygon with shapely.

Nothing here uses the planner's stability, stance or kinematics code: the robot CoM is
pinocchio's ``centerOfMass`` on the URDF (mimic joints from the URDF's ``<mimic>``), the
system CoM is the paper's equation 1 written out, and the support polygon is the convex
hull of the sole boxes (from the URDF's ``<collision>``) of the feet that touch the ground.
The URDF reading, the configuration mapping, the hull and the signed distance are the plan
checker's (tests/plan_checker.py), so plans and survey states are checked the same way.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from plan_checker import _box_sizes, _mimics, _pin_q, _signed_margin, _sole_hull
from shapely.geometry import Polygon

from planner.robot.registry import urdf_path

#: A sole whose frame is this close to z = 0 stands on the ground.
ON_GROUND_M = 1e-3


class Independent:
    def __init__(self, robot_name: str, joint_names: list[str]):
        urdf = str(urdf_path(robot_name))
        self.model = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
        self.data = self.model.createData()
        self.total_mass = float(pin.computeTotalMass(self.model))
        self.col = {str(n): i for i, n in enumerate(joint_names)}
        self.mimics = _mimics(urdf)
        self.sole_size = _box_sizes(urdf, ("l_sole", "r_sole"))

    def pin_q(self, base_pose: np.ndarray, q: np.ndarray) -> np.ndarray:
        return _pin_q(self.model, self.mimics, self.col, base_pose, q)

    def robot_com(self, base_pose: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """Robot CoM (N, 3) of configurations Q (N, n) in joint_names order."""
        return np.array([pin.centerOfMass(self.model, self.data, self.pin_q(base_pose, q), False).copy() for q in Q])

    def frame(self, base_pose: np.ndarray, q: np.ndarray, name: str) -> pin.SE3:
        pin.framesForwardKinematics(self.model, self.data, self.pin_q(base_pose, q))
        return self.data.oMf[self.model.getFrameId(name)].copy()

    @staticmethod
    def object_com(object_pose: np.ndarray, com_local: np.ndarray) -> np.ndarray:
        """World CoM (N, 3) of the object at poses (N, 7)."""
        return np.array([pin.XYZQUATToSE3(np.asarray(p, float)).act(np.asarray(com_local, float)) for p in object_pose])

    def system_com(self, robot_com: np.ndarray, object_com: np.ndarray, mass: float) -> np.ndarray:
        """The paper's equation 1: (M robot + m object) / (M + m)."""
        M = self.total_mass
        return (M * robot_com + mass * object_com) / (M + mass)

    def support_polygon(self, base_pose: np.ndarray, q: np.ndarray) -> Polygon:
        """Convex hull of the sole boxes whose frames are on the ground."""
        placed = ((self.frame(base_pose, q, sole), size) for sole, size in self.sole_size.items())
        return _sole_hull((T, size) for T, size in placed if abs(T.translation[2]) <= ON_GROUND_M)

    @staticmethod
    def margins(polygon: Polygon, xy: np.ndarray) -> np.ndarray:
        """Signed distance of each point to the polygon's edge, inside positive."""
        return np.array([_signed_margin(polygon, x, y) for x, y in xy])
