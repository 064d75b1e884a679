"""Unitree's G1 (example-robot-data) from its spec file alone, with rigid hands: no jaw joint, contact grasps
on the palm side, the object attached at the TCP; ``g1-upright`` planned, re-verified by the independent
checker and passed by the gate; the stances G1's legs reach."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cmeel", reason="G1 needs the example-robot-data package (the `talos` extra)")

from .robot_checks import assert_the_gate_passes, builtin_plan, small_survey

SPEC = "robot_data/g1.yaml"


@pytest.fixture(scope="module")
def g1():
    from planner.robot.model import load_robot

    return load_robot("g1")


def test_g1_has_rigid_hands_and_the_specs_hand_boxes(g1):
    from planner.robot.urdf_geometry import collision_primitives

    assert all(arm.gripper is None for arm in g1.spec.arms.values())
    assert not any("gripper" in n or "jaw" in n for n in g1.joint_names) and g1.nq == 29
    boxes = [p for p in collision_primitives(g1.urdf_path) if p.link == "left_rubber_hand"]
    assert [(p.kind, p.dims) for p in boxes] == [("box", (0.132, 0.067, 0.106))]


def test_contact_grasps_put_the_tcp_on_a_face_pressing_inward(g1):
    """Every grasp's TCP lies on the box's surface with its z axis along the inward normal, and the hand,
    moved back 4 mm along its approach, is clear of the box."""
    from planner.grasping.grasps import GraspSettings, compute_grasps
    from planner.scene.bodies import object_bodies, shapes_collide
    from planner.scene.hand import hand_bodies, hand_geometry
    from planner.scene.objects import build_object
    from schemas.scenario import ObjectDef

    obj = build_object(ObjectDef(shape="box", size=[0.10, 0.12, 0.22], mass_kg=1.0))
    hand = hand_geometry(g1, "right")
    grasps = compute_grasps(obj, hand, GraspSettings())
    assert len(grasps) > 50 and all(g.opening_m == 0.0 and g.jaw_value == 0.0 for g in grasps)
    half = np.array([0.05, 0.06, 0.11])
    centre = obj.mesh.bounds.mean(axis=0)
    faces = set()
    for g in grasps:
        p, z = g.T_obj_tcp[:3, 3] - centre, g.T_obj_tcp[:3, 2]
        axis = int(np.argmax(np.abs(z)))
        assert abs(abs(z[axis]) - 1.0) < 1e-9  # flat on a face
        assert abs(p[axis] + np.sign(z[axis]) * half[axis]) < 1e-9  # on that face, pressing into the box
        assert np.all(np.abs(p) <= half + 1e-9)
        faces.add((axis, np.sign(z[axis])))
    assert len(faces) == 6
    back = np.eye(4)
    back[2, 3] = -0.004
    hb = hand_bodies(hand, 0.0)
    poses = np.array([[g.T_obj_tcp @ back @ b.local for b in hb] for g in grasps])
    ob = object_bodies(obj)
    assert not shapes_collide(hb, poses, ob, np.array([b.local for b in ob])).any()


def test_the_stances_g1s_legs_reach(g1):
    """Upright, staggered and one-legged solve; crouched (the pelvis 0.15 m lower) is beyond G1's ankle range
    from any upright pelvis height that also lets it take the staggered step, and says by how much."""
    from planner.stability.stances import StanceError, solve_stance

    for name in ("upright", "staggered", "one-legged"):
        assert solve_stance(g1, name).margin > 0.02, name
    with pytest.raises(StanceError, match="cannot reach its placement"):
        solve_stance(g1, "crouched")


@pytest.fixture(scope="module")
def g1_plan():
    return builtin_plan("g1-upright", "left-left")


def test_g1_upright_plans_and_the_independent_checker_agrees(g1_plan):
    from plan_checker import check_plan

    plan = g1_plan
    assert plan["status"] == "solved", plan["failure"]
    assert plan["robot"]["name"] == "g1" and plan["min_margin_m"] >= plan["threshold_m"] == 0.047
    assert 0.0 < max(p["effort_ratio"] for p in plan["trajectory"]) < 1.0
    assert check_plan(plan, sample_every=5, robot_spec=SPEC).errors == []


def test_the_gate_passes_the_g1_upright_plan(g1_plan):
    assert_the_gate_passes(g1_plan)


def test_the_demo_shows_the_stance_g1_cannot_take_and_goes_on(tmp_path):
    """`regrasp demo --robot g1 --stances-only`: the crouch G1 cannot take is shown with its reason; the task's
    own stance (upright) solves, so the demo does not stop there."""
    from click.testing import CliRunner

    from service.cli.main import cli

    res = CliRunner().invoke(cli, ["demo", "--robot", "g1", "--out", str(tmp_path), "--stances-only"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    assert "crouched: beyond g1 (above); the task stands upright" in flat and "r_sole" in flat
    assert sorted(p.name for p in tmp_path.glob("stance-*.png")) == [
        "stance-one-legged.png", "stance-staggered.png", "stance-upright.png"]


def test_a_small_survey_of_g1_upright_counts_the_one_hand_configurations():
    doc, rows = small_survey("g1-upright")
    assert doc["robot"]["name"] == "g1"
    for hands in ("left-left", "right-right"):
        assert rows[hands]["stable"] + rows[hands]["unstable"] == 200 and 0.0 < rows[hands]["ratio"] <= 1.0
