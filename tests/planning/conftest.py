"""Fixtures of the geometry tests: objects, grasp sets and a scenario world, built once."""

from __future__ import annotations

import numpy as np
import pytest

from schemas.scenario import ObjectDef


@pytest.fixture(scope="session")
def grasp_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("grasp-cache")


@pytest.fixture(scope="session")
def box_obj():
    from planner.scene.objects import build_object

    return build_object(ObjectDef(name="box", shape="box", size=[0.06, 0.10, 0.20], mass_kg=1.0))


@pytest.fixture(scope="session")
def drill_obj():
    from planner.scene.objects import build_object

    return build_object(ObjectDef(name="drill", shape="drill", mass_kg=1.3))


@pytest.fixture(scope="session")
def box_grasps(hrp5p, box_obj, grasp_cache):
    from planner.grasping.grasps import plan_grasps

    return plan_grasps(box_obj, hrp5p, "right", cache_directory=grasp_cache)


@pytest.fixture(scope="session")
def drill_grasps(hrp5p, drill_obj, grasp_cache):
    from planner.grasping.grasps import plan_grasps

    return {side: plan_grasps(drill_obj, hrp5p, side, cache_directory=grasp_cache) for side in ("right", "left")}


@pytest.fixture(scope="session")
def table_box():
    from planner.scene.bodies import EnvBox
    from planner.transforms import make_transform

    return EnvBox("table", make_transform(p=[0.60, 0.0, 0.73]), (0.50, 1.40, 0.04))


@pytest.fixture(scope="session")
def upright_world(hrp5p, stances, table_box, drill_obj):
    from planner.scene.collision import CollisionWorld

    st = stances["upright"]
    return CollisionWorld(hrp5p, [table_box], drill_obj, reference_postures=[(st.base_pose, st.q)])


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)



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
