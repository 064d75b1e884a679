"""TALOS (example-robot-data) from its spec file alone: derived URDF, fitted collision boxes, stances, limits,
the paper's upright task (``talos-upright``) planned, re-verified by the independent checker, passed by the gate,
surveyed and run through the demo."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

pytest.importorskip("cmeel", reason="TALOS needs the example-robot-data package (the `talos` extra)")

from .robot_checks import assert_the_gate_passes, builtin_plan, small_survey

SPEC = "robot_data/talos.yaml"


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


def test_every_mesh_point_is_inside_a_fitted_box(talos):
    """The octant boxes of a large mesh cover the triangles clipped to each octant, so no part of the surface
    is left out (the vertices of an octant alone left up to 70 % of the arm and leg meshes uncovered)."""
    import trimesh

    from planner.robot.spec_file import SPLIT_ABOVE_M, _fit_boxes, resolve_urdf

    urdf = resolve_urdf("package:///example-robot-data/robots/talos_data/robots/talos_full_v2.urdf", talos.urdf_path.parent, {})
    mesh = trimesh.load(str(urdf.parent.parent / "meshes" / "arm" / "arm_5_collision.STL"), force="mesh")
    boxes = _fit_boxes(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    assert len(boxes) > 1 and mesh.extents.max() > SPLIT_ABOVE_M
    points, _ = trimesh.sample.sample_surface(mesh, 2000, seed=0)
    inside = np.zeros(len(points), dtype=bool)
    for T, extents in boxes:
        local = (points - T[:3, 3]) @ T[:3, :3]
        inside |= np.all(np.abs(local) <= extents / 2 + 1e-9, axis=1)
    assert inside.all()


def test_the_srdf_collision_matrix_and_posture_are_read(talos):
    """The spec names TALOS's own SRDF: its <disable_collisions> pairs are skipped, its half_sitting posture is
    the default one (so the upper arms clear the torso there, and their pairs are checked on both sides)."""
    from planner.scene.collision import CollisionWorld

    pairs = set(talos.spec.disabled_collisions)
    assert ("arm_left_5_link", "wrist_left_ft_link") in pairs and len(pairs) > 400
    assert talos.spec.default_posture_rad["arm_left_4_joint"] == pytest.approx(-0.525366)
    disabled = CollisionWorld(talos).disabled
    for side in ("left", "right"):
        assert (f"arm_{side}_3_link", "torso_2_link") not in disabled


@pytest.fixture(scope="module")
def talos_plan():
    return builtin_plan("talos-upright", "left-left")


def test_talos_upright_plans_and_the_independent_checker_agrees(talos_plan):
    from plan_checker import check_plan

    plan = talos_plan
    assert plan["status"] == "solved", plan["failure"]
    assert plan["robot"]["name"] == "talos" and plan["object"]["mass_kg"] == 2.0
    assert plan["min_margin_m"] >= plan["threshold_m"] == 0.055
    assert 0.0 < max(p["effort_ratio"] for p in plan["trajectory"]) < 1.0
    assert plan["stats"]["time_s"] < 60
    assert check_plan(plan, sample_every=5, robot_spec=SPEC).errors == []


def test_the_gate_passes_the_talos_upright_plan(talos_plan):
    assert_the_gate_passes(talos_plan)


def test_the_upright_task_fitted_to_talos_keeps_its_wrists_with_the_papers_8_kg():
    """Fitted to TALOS, the upright task's own mass is within its 8 N*m wrists; with the paper's 8 kg
    (`--mass-kg 8`) the planner keeps to grasps the wrists hold, and the gate's own torques agree."""
    from planner.jobs.plan_job import PlanOptions, plan_scenario
    from planner.scene.scenarios import load_builtin

    doc = plan_scenario(load_builtin("upright"), PlanOptions(robot="talos", mass_kg=8.0, hands="right-right"))
    assert doc["scenario"]["fitted"]["mass_kg"] < 2.0 and doc["object"]["mass_kg"] == 8.0
    assert doc["status"] == "solved", doc["failure"]
    assert max(p["effort_ratio"] for p in doc["trajectory"]) <= 1.0
    assert_the_gate_passes(doc)


def test_a_small_survey_of_talos_upright_has_the_four_hand_configurations():
    doc, rows = small_survey("talos-upright")
    assert doc["robot"]["name"] == "talos" and set(rows) == {"left-left", "right-right", "left-right", "right-left"}
    surveyed = {h: r for h, r in rows.items() if r["ratio"] is not None}
    assert {"left-left", "right-right"} <= set(surveyed)  # one arm carries it across on every key path
    for r in surveyed.values():
        assert 0.0 < r["ratio"] <= 1.0 and r["seeds"] == 2
        assert r["ratio"] == r["stable"] / (r["stable"] + r["unstable"])
    best = max(surveyed.values(), key=lambda r: r["ratio"])
    assert doc["recommended"] in {h for h, r in surveyed.items() if r["ratio"] == best["ratio"]}
    lo, hi = surveyed[doc["recommended"]]["ratio_ci95"]
    overlapping = {h for h, r in surveyed.items()
                   if h != doc["recommended"] and r["ratio_ci95"][1] >= lo and r["ratio_ci95"][0] <= hi}
    assert set(doc["indistinguishable"]) == overlapping
