"""Fixtures of the motion tests: one robot, the upright stance, an evaluator and a grasp."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from shapely.geometry import Point, Polygon

from planner.robot.model import load_robot
from planner.stability.evaluator import HoldSpec, StateEvaluator
from planner.stability.stances import solve_stance

COM_LOCAL = np.array([0.15, 0.08, 0.15])


@pytest.fixture(scope="session")
def robot():
    return load_robot("hrp5p")


@pytest.fixture(scope="session")
def upright(robot):
    return solve_stance(robot, "upright")


@pytest.fixture(scope="session")
def evaluator(robot, upright):
    return StateEvaluator(robot, upright, threshold_m=0.03, object_mass=3.0, com_local=COM_LOCAL)


@pytest.fixture(scope="session")
def hold_right():
    T = np.eye(4)
    T[:3, 3] = [0.02, -0.01, -0.12]  # the TCP 12 cm below the object frame origin
    return HoldSpec("right", T)


@pytest.fixture(scope="session")
def right_active(robot):
    return np.r_[robot.waist_indices(), robot.arm_indices("right")]


class Independent:
    """Recomputes CoM and margin from pinocchio and shapely, not through the planner's code."""

    def __init__(self, robot, stance, mass, com_local):
        self.robot, self.stance, self.mass, self.com_local = robot, stance, mass, np.asarray(com_local)
        self.data = robot.pin_model.createData()
        self.poly = Polygon(stance.polygon.vertices)

    def system_com(self, q, hold):
        model = self.robot.pin_model
        qp = self.robot.to_pin_q(self.stance.base_pose, q)
        c_robot = np.array(pin.centerOfMass(model, self.data, qp))
        if hold is None:
            return c_robot
        pin.forwardKinematics(model, self.data, qp)
        fid = model.getFrameId(self.robot.spec.arms[hold.tcp_side].tcp)
        T_tcp = pin.updateFramePlacement(model, self.data, fid).homogeneous
        T_obj = T_tcp @ np.linalg.inv(hold.T_obj_tcp)
        c_obj = T_obj[:3, :3] @ self.com_local + T_obj[:3, 3]
        M = pin.computeTotalMass(model)
        return (M * c_robot + self.mass * c_obj) / (M + self.mass)

    def margin(self, q, hold):
        c = self.system_com(q, hold)
        p = Point(c[0], c[1])
        d = self.poly.exterior.distance(p)
        return d if self.poly.contains(p) else -d


@pytest.fixture(scope="session")
def independent(robot, upright):
    return Independent(robot, upright, 3.0, COM_LOCAL)
