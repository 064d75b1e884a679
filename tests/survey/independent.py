"""An independent look at stored survey states: the URDF in pinocchio, the polygon with shapely.

Nothing here uses the planner's stability, stance or kinematics code: the robot CoM is
pinocchio's ``centerOfMass`` on the URDF (mimic joints from the URDF's ``<mimic>``), the
system CoM is the paper's equation 1 written out, and the support polygon is the convex
hull of the sole boxes (from the URDF's ``<collision>``) of the feet that touch the ground.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
from shapely.geometry import MultiPoint, Point, Polygon

from planner.robots.registry import urdf_path

#: A sole whose frame is this close to z = 0 stands on the ground.
ON_GROUND_M = 1e-3


class Independent:
    def __init__(self, robot_name: str, joint_names: list[str]):
        urdf = str(urdf_path(robot_name))
        self.model = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
        self.data = self.model.createData()
        self.total_mass = float(pin.computeTotalMass(self.model))
        self.col = {str(n): i for i, n in enumerate(joint_names)}
        root = ET.parse(urdf).getroot()
        self.mimics = {}
        for j in root.iter("joint"):
            m = j.find("mimic")
            if m is not None:
                self.mimics[j.attrib["name"]] = (m.attrib["joint"], float(m.attrib.get("multiplier", 1)),
                                                 float(m.attrib.get("offset", 0)))
        self.sole_size = {}
        for link in root.iter("link"):
            if link.attrib["name"] in ("l_sole", "r_sole"):
                sx, sy, _ = (float(v) for v in link.find("collision/geometry/box").attrib["size"].split())
                self.sole_size[link.attrib["name"]] = (sx, sy)

    def pin_q(self, base_pose: np.ndarray, q: np.ndarray) -> np.ndarray:
        out = pin.neutral(self.model)
        out[:7] = base_pose
        for jid in range(2, self.model.njoints):
            name = self.model.names[jid]
            if name in self.mimics:
                master, k, b = self.mimics[name]
                out[self.model.idx_qs[jid]] = k * q[self.col[master]] + b
            else:
                out[self.model.idx_qs[jid]] = q[self.col[name]]
        return out

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
        corners = []
        for sole, (sx, sy) in self.sole_size.items():
            T = self.frame(base_pose, q, sole)
            if abs(T.translation[2]) > ON_GROUND_M:
                continue
            for cx, cy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
                corners.append(T.act(np.array([cx * sx / 2, cy * sy / 2, 0.0]))[:2])
        return MultiPoint(corners).convex_hull

    @staticmethod
    def margins(polygon: Polygon, xy: np.ndarray) -> np.ndarray:
        """Signed distance of each point to the polygon's edge, inside positive."""
        out = []
        for x, y in xy:
            p = Point(float(x), float(y))
            d = polygon.exterior.distance(p)
            out.append(d if polygon.contains(p) else -d)
        return np.array(out)

