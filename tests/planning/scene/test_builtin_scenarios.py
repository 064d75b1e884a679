"""Built-in scenarios: they load, their objects build, start and goal rest on a table, and the
stance posture is free of collision with the object at both."""

from __future__ import annotations

import numpy as np
import pytest

from planner.scene.bodies import environment_boxes
from planner.scene.collision import CollisionWorld
from planner.scene.objects import build_object
from planner.scene.placements import check_resting
from planner.scene.scenarios import builtin_names, load_builtin
from planner.stability.stances import solve_stance
from planner.transforms import pose7_to_matrix

PAPER = {
    "upright": (8.0, (0.15, 0.08, 0.15), 0.06, "upright"),
    "staggered": (5.0, (-0.15, 0.08, 0.15), 0.03, "staggered"),
    "crouched": (15.0, (-0.15, 0.08, 0.15), 0.06, "crouched"),
    "one-legged": (5.0, (0.0, 0.0, 0.2), 0.03, "one-legged"),
}


def test_all_builtins_present():
    assert set(builtin_names()) >= {*PAPER, "drill-handover", "drill-upright"}


@pytest.mark.parametrize("name", sorted(PAPER))
def test_paper_parameters(name):
    sc = load_builtin(name)
    mass, com, threshold, stance = PAPER[name]
    assert sc.object.mass_kg == mass and sc.threshold_m == threshold and sc.stance == stance
    obj = build_object(sc.object)
    assert np.allclose(obj.com_local, com)
    # the graspable part (<= 70 mm) passes within the torque filter's reach of the CoM
    assert np.allclose(obj.mesh.center_mass, com, atol=1e-6)


@pytest.mark.parametrize("name", ["upright", "staggered", "crouched", "one-legged", "drill-handover", "drill-upright"])
def test_start_goal_rest_and_stance_is_free(hrp5p, name):
    sc = load_builtin(name)
    obj = build_object(sc.object)
    tables = environment_boxes(sc)[: len(sc.tables)]
    st = solve_stance(hrp5p, sc.stance)
    world = CollisionWorld.from_scenario(hrp5p, sc, obj, reference_postures=[(st.base_pose, st.q)])
    for pose in (sc.start_pose, sc.goal_pose):
        T = pose7_to_matrix(pose)
        info = check_resting(obj, T, tables)
        assert info.reference >= 0
        assert world.object_pose_clear(T) is None
        assert world.check(st.base_pose, st.q, free_object_pose=T) is None


def test_drill_scenarios():
    h = load_builtin("drill-handover")
    assert h.hands == "right-left" and h.threshold_m == 0.055 and h.object.shape == "drill"
    u = load_builtin("drill-upright")
    obj = build_object(u.object)
    down_start = pose7_to_matrix(u.start_pose)[:3, :3].T @ np.array([0, 0, -1.0])
    down_goal = pose7_to_matrix(u.goal_pose)[:3, :3].T @ np.array([0, 0, -1.0])
    assert abs(down_start[1]) > 0.99  # lying on a side
    assert np.allclose(down_goal, [0, 0, -1])  # standing on the battery
    assert obj.mass_kg == 1.3
