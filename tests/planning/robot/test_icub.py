"""iCub (example-robot-data's ``icub_reduced.urdf``) from a spec file written here, with no code of its own: a
humanoid whose root frame faces backwards (its soles' x axes point along the root's -x), whose arm and waist
joints turn about unaligned axes, whose knees flex the negative way, and whose hands are rigid. The stance
turns the root to face the world's +x, the batch IK turns those joints, and a small pick-and-place plans,
re-verified by the independent checker and passed by the gate."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from .robot_checks import assert_the_gate_passes

pytest.importorskip("cmeel", reason="iCub needs the example-robot-data package (the `talos` extra)")

LEG = ["hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll"]
SPEC = {
    "schema": "regrasp.robot/1",
    "name": "icub",
    "urdf": "package:///example-robot-data/robots/icub_description/robots/icub_reduced.urdf",
    # the URDF's own sole frames; the spec gives their size (the foot's flat part)
    "feet": {side: {"frame": f"{side[0]}_sole", "link": f"{side[0]}_foot", "size": [0.12, 0.05],
                    "chain": [f"{side[0]}_{j}" for j in LEG]} for side in ("left", "right")},
    # a flat face of each hand (its collision mesh is 24 mm thick about the link's z), z out of it
    "hands": {"left": {"frame": "l_tcp", "link": "l_hand", "pose_in_link": [0.045, 0.02, -0.012, 1, 0, 0, 0], "jaw": None},
              "right": {"frame": "r_tcp", "link": "r_hand", "pose_in_link": [0.045, 0.02, 0.012, 0, 0, 0, 1], "jaw": None}},
    "upright": {"pelvis_height_m": 0.55, "foot_y_m": 0.07},
    "acceleration_limits": {"default": 2.0},
}


@pytest.fixture(scope="module")
def icub_spec(tmp_path_factory):
    path = tmp_path_factory.mktemp("icub") / "icub.yaml"
    path.write_text(yaml.safe_dump(SPEC))
    return path


@pytest.fixture(scope="module")
def icub(icub_spec):
    from planner.robot.model import load_robot

    return load_robot(str(icub_spec))


def test_the_stance_turns_icubs_root_to_face_forward(icub):
    """The root faces backwards, so the stance turns it half a turn: the soles' x axes point along the world's
    +x, the left sole at +y; the knees bend the negative way."""
    import pinocchio as pin

    from planner.stability.stances import solve_stance

    st = solve_stance(icub, "upright")
    assert abs(abs(st.base_pose[5]) - 1.0) < 1e-6  # a half turn about z
    data = icub.create_data()
    pin.framesForwardKinematics(icub.pin_model, data, icub.to_pin_q(st.base_pose, st.q))
    for side, y in (("left", 0.07), ("right", -0.07)):
        M = data.oMf[icub.frame_id(icub.spec.feet[side].frame)]
        assert np.allclose(M.rotation, np.eye(3), atol=1e-3) and M.translation[1] == pytest.approx(y, abs=1e-3)
        assert st.q[icub.joint_index(f"{side[0]}_knee")] < -0.05
    assert st.margin > 0.03
    for name in ("staggered", "one-legged"):
        assert solve_stance(icub, name).margin > 0.0, name


def test_batch_ik_turns_unaligned_joints_to_reachable_targets(icub):
    """Targets made by forward kinematics of random arm postures are reached, to the IK's tolerances, by the
    batch descent through iCub's unaligned torso and shoulder joints."""
    import pinocchio as pin

    from planner.kinematics.batch import BatchKinematics
    from planner.motion.ik_batch import BatchIk
    from planner.motion.ik_rules import IkSettings
    from planner.stability.stances import solve_stance

    st = solve_stance(icub, "upright")
    settings = IkSettings()
    ik = BatchIk(icub, BatchKinematics(icub), settings)
    active = ik.active_columns("right")
    assert {j for j in ("torso_yaw", "r_shoulder_roll", "r_shoulder_yaw")} <= {icub.joint_names[c] for c in active}
    rng = np.random.default_rng(3)
    data = icub.create_data()
    tcp = icub.frame_id(icub.spec.arms["right"].tcp)
    targets, Q = [], []
    for _ in range(40):
        q = st.q.copy()
        q[active] = st.q[active] + rng.uniform(-0.4, 0.4, active.size)
        q = np.clip(q, icub.lower, icub.upper)
        pin.framesForwardKinematics(icub.pin_model, data, icub.to_pin_q(st.base_pose, q))
        targets.append(data.oMf[tcp].homogeneous.copy())
        Q.append(q)
    res = ik.solve("right", np.array(targets), st.base_pose, st.q, st.q)
    assert res.ok.mean() >= 0.8, res.ok.mean()
    for q, T in zip(res.q[res.ok], np.array(targets)[res.ok]):
        pin.framesForwardKinematics(icub.pin_model, data, icub.to_pin_q(st.base_pose, q))
        assert np.linalg.norm(data.oMf[tcp].translation - T[:3, 3]) <= settings.pos_tol_m + 1e-9


def test_a_pick_and_place_with_icub_plans_and_the_checker_and_the_gate_agree(icub_spec, tmp_path, monkeypatch):
    """0.1 kg (iCub's wrists are limited to 0.45-0.65 N*m) moved 0.10 m across a low table with the right hand."""
    from plan_checker import check_plan

    from planner.jobs.plan_job import PlanOptions, plan_scenario
    from planner.scene.scenarios import parse_scenario

    sc = parse_scenario({
        "schema": "regrasp.scenario/1", "name": "icub-box", "robot": str(icub_spec), "stance": "upright",
        "object": {"shape": "box", "size": [0.05, 0.06, 0.10], "mass_kg": 0.1},
        "start_pose": [0.20, -0.14, 0.43, 0, 0, 0, 1], "goal_pose": [0.20, -0.04, 0.43, 0, 0, 0, 1],
        "tables": [{"name": "table", "pose": [0.42, 0, 0.19, 0, 0, 0, 1], "size": [0.5, 1.0, 0.38]}],
        "threshold_m": 0.03, "hands": "right-right", "limits": {"time_s": 60, "max_iterations": 3000}, "seed": 1,
    })
    plan = plan_scenario(sc, PlanOptions())
    assert plan["status"] == "solved", plan["failure"]
    assert plan["min_margin_m"] >= 0.03 and 0.0 < max(p["effort_ratio"] for p in plan["trajectory"]) <= 1.0
    assert check_plan(plan, sample_every=5, robot_spec=str(icub_spec)).errors == []
    monkeypatch.setenv("REGRASP_ROBOT_DIRS", str(icub_spec.parent))
    assert_the_gate_passes(plan)
