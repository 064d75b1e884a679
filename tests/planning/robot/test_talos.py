"""TALOS (example-robot-data) from its spec file alone: derived URDF, fitted collision boxes, stances, limits."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

pytest.importorskip("cmeel")


@pytest.fixture(scope="module")
def talos():
    from planner.robot.model import load_robot

    return load_robot("talos")


def test_the_derived_urdf_lives_in_the_cache_with_boxes_for_every_mesh(talos):
    import robot_data

    root = ET.parse(talos.urdf_path).getroot()
    assert root.findall(".//collision/geometry/mesh") == []
    assert len(root.findall(".//collision/geometry/box")) > 40
    assert not talos.urdf_path.is_relative_to(robot_data.data_dir())
    assert {"l_sole", "r_sole", "l_tcp", "r_tcp"} <= {el.attrib["name"] for el in root.findall("link")}


def test_the_four_stances_solve_within_the_limits(talos):
    from planner.stability.effort import EffortEvaluator
    from planner.stability.stances import BUILTIN_STANCES, solve_stance

    for name in BUILTIN_STANCES:
        st = solve_stance(talos, name)
        assert st.margin > 0.03, name
        ratio = EffortEvaluator(talos, st, 0.0, np.zeros(3)).evaluate(st.q[None], "none").effort_ratio[0]
        assert 0.0 < ratio < 1.0, name


def test_effort_limits_come_from_talos_urdf_and_the_chains_from_its_tree(talos):
    from planner.stability.effort import effort_limits

    limits = effort_limits(talos)
    assert "gripper_left_joint" not in limits and len(limits) == 30
    assert talos.spec.waist == ["torso_1_joint", "torso_2_joint"]
    assert talos.spec.arms["left"].chain == [f"arm_left_{k}_joint" for k in range(1, 8)]
    root = ET.parse(talos.urdf_path).getroot()
    urdf_effort = {j.attrib["name"]: float(j.find("limit").attrib["effort"]) for j in root.iter("joint")
                   if j.find("limit") is not None and "effort" in j.find("limit").attrib}
    assert all(limits[j] == urdf_effort[j] for j in limits)


def test_talos_hands_yield_grasps_of_a_box_that_fits_the_jaws(talos):
    from planner.grasping.grasps import GraspSettings, compute_grasps
    from planner.scene.hand import hand_geometry
    from planner.scene.objects import build_object
    from schemas.scenario import ObjectDef

    obj = build_object(ObjectDef(name="box", shape="box", size=[0.12, 0.06, 0.20], mass_kg=2.0))
    grasps = compute_grasps(obj, hand_geometry(talos, "right"), GraspSettings())
    assert grasps and all(-0.96 < g.jaw_value < 0.0 for g in grasps)
