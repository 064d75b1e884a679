"""T-RRT and exploration with the real collision checker plugged in through the callbacks."""

from __future__ import annotations

import numpy as np
import pytest

collision = pytest.importorskip("planner.scene.collision")

from planner.motion.edge_checks import make_validity  # noqa: E402
from planner.motion.trrt import plan_motion  # noqa: E402
from planner.survey.counting import ExploreLeg, explore_counted  # noqa: E402


@pytest.fixture(scope="module")
def world(robot, upright, right_active):
    from planner.scene.objects import build_object
    from schemas.scenario import ObjectDef

    table = np.eye(4)
    table[:3, 3] = [0.9, 0.0, 0.25]
    obj = build_object(ObjectDef(shape="box", size=[0.06, 0.10, 0.20], mass_kg=3.0))
    names = [robot.joint_names[i] for i in right_active]
    return collision.CollisionWorld(robot, [collision.EnvBox("table", table, (0.5, 1.2, 0.5))], obj,
                                    moving_joints=names, reference_postures=[(upright.base_pose, upright.q)])


def test_planned_path_is_collision_free_and_stable(robot, upright, evaluator, hold_right, right_active, world, independent):
    held = [("right", hold_right.T_obj_tcp)]

    def collision_free(Q):
        return ~world.check_batch(upright.base_pose, Q, held=held).collides

    validity = make_validity(evaluator, hold_right, right_active, collision_free)
    start = upright.q.copy()
    goal = start.copy()
    goal[right_active] = np.clip([0.1, 0.0, 0.5, 0.2, -0.6, -0.5, 0.3, -1.2, 0.3, 0.2, 0.1, 0.0],
                                 robot.lower[right_active], robot.upper[right_active])
    assert validity(np.vstack([start, goal]))[0].all()
    res = plan_motion(start, goal, right_active, validity, robot.lower, robot.upper, np.random.default_rng(0))
    assert res.ok, res.reason
    for a, b in zip(res.path[:-1], res.path[1:]):
        n = max(1, int(np.ceil(np.abs(b - a).max() / 0.02 - 1e-9)))
        for s in np.arange(n + 1) / n:
            q = a + s * (b - a)
            assert world.check(upright.base_pose, q, held=held) is None
            assert independent.margin(q, hold_right) >= 0.03 - 1e-12


def test_explored_states_never_collide(robot, upright, evaluator, hold_right, right_active, world):
    held = [("right", hold_right.T_obj_tcp)]
    start = upright.q.copy()
    goal = start.copy()
    goal[right_active] = np.clip(start[right_active] + 0.5, robot.lower[right_active], robot.upper[right_active])

    def collision_free(Q):
        return ~world.check_batch(upright.base_pose, Q, held=held).collides

    ex = explore_counted([ExploreLeg(start, goal, hold_right, right_active, collision_free)], evaluator,
                         np.random.default_rng(4), budget=600)
    assert len(ex.q) == 600
    assert not world.check_batch(upright.base_pose, ex.q, held=held).collides.any()
