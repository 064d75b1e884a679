"""JVRC-1: the derived URDF, its contract frames, the jaw mimics, stances and the 80 mm sole."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from click.testing import CliRunner

from planner.kinematics.batch import BatchKinematics
from planner.robot import jvrc1_urdf
from planner.robot.model import frame_poses, load_robot
from planner.stability.robot_com import robot_com as center_of_mass
from planner.robot.registry import robot_names, urdf_path
from planner.robot.urdf_geometry import collision_primitives
from planner.stability.stances import (
    BUILTIN_STANCES,
    StanceError,
    sole_size,
    solve_stance,
)
from schemas.stance import StanceDef

SIDES = (("l", "L"), ("r", "R"))


@pytest.fixture(scope="module")
def jvrc1():
    return load_robot("jvrc1")


@pytest.fixture(scope="module")
def jvrc1_stances(jvrc1):
    return {name: solve_stance(jvrc1, name) for name in BUILTIN_STANCES}


@pytest.fixture(scope="module")
def package_root():
    import jvrc_description

    return ET.parse(jvrc_description.urdf_path).getroot()


@pytest.fixture(scope="module")
def derived():
    pytest.importorskip("collada", reason="reading the package's Collada meshes needs pycollada")
    return jvrc1_urdf.derive()


# ---------------------------------------------------------------- the derived file


def test_regenerating_gives_the_committed_files(derived):
    text, lic, _, _ = derived
    assert text == jvrc1_urdf.URDF_PATH.read_text(encoding="utf-8")
    assert lic == jvrc1_urdf.LICENSE_PATH.read_text(encoding="utf-8")


def test_license_notice_is_kept_in_the_urdf_and_beside_it():
    head = urdf_path("jvrc1").read_text(encoding="utf-8").split("<robot", 1)[0]
    lic = jvrc1_urdf.LICENSE_PATH.read_text(encoding="utf-8")
    for text in (head, lic):
        assert "Copyright (c) 2012-2019, CNRS-UM LIRMM, CNRS-AIST JRL" in text
        assert "Copyright (c) 2022, Stéphane Caron" in text
        assert "Redistributions of source code must retain the above copyright notice" in text


def test_registry_lists_jvrc1_and_pinocchio_loads_it_without_meshes():
    assert "jvrc1" in robot_names()
    path = urdf_path("jvrc1")
    assert path.is_absolute() and path.is_file()
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    assert model.names[1] == "root_joint"
    assert "mesh" not in path.read_text(encoding="utf-8").split("<robot", 1)[1]
    # Every collision is a primitive the shared parser reads.
    kinds = {p.kind for p in collision_primitives(path)}
    assert kinds == {"box"}


def test_mass_joints_and_limits_as_the_package_has_them(jvrc1, package_root):
    package_mass = sum(float(m.attrib["value"]) for m in package_root.iter("mass"))
    assert package_mass == pytest.approx(62.4, abs=1e-9)
    assert jvrc1.total_mass == pytest.approx(package_mass, abs=1e-9)
    # 34 actuated joints in the package: 32 body joints + the two thumb masters, which
    # the derivation replaces by the jaw joints.
    assert jvrc1.nq == 34
    assert "L_JAW" in jvrc1.joint_names and "R_JAW" in jvrc1.joint_names
    assert not any("THUMB" in n or "INDEX" in n or "LITTLE" in n for n in jvrc1.joint_names)
    model = jvrc1.pin_model
    assert all(model.nqs[j] == 1 for j in range(2, model.njoints))
    for joint in package_root.iter("joint"):
        name = joint.attrib["name"]
        if name in jvrc1.joint_names:
            limit = joint.find("limit")
            i = jvrc1.joint_index(name)
            assert jvrc1.lower[i] == pytest.approx(float(limit.attrib["lower"]))
            assert jvrc1.upper[i] == pytest.approx(float(limit.attrib["upper"]))
            assert jvrc1.velocity_limit[i] == pytest.approx(float(limit.attrib["velocity"]))
    assert np.all(jvrc1.acceleration_limit > 0)


# ---------------------------------------------------------------- contract frames


def test_sole_frames_z_up_at_the_bottom_of_the_foot(jvrc1):
    """Zero posture, base upright: sole frames are level and are the feet's lowest points."""
    data = jvrc1.create_data()
    q = np.clip(np.zeros(jvrc1.nq), jvrc1.lower, jvrc1.upper)
    base = np.array([0, 0, 1.0, 0, 0, 0, 1.0])
    pin.framesForwardKinematics(jvrc1.pin_model, data, jvrc1.to_pin_q(base, q))
    for s, S in SIDES:
        M = data.oMf[jvrc1.frame_id(f"{s}_sole")]
        assert np.allclose(M.rotation, np.eye(3), atol=1e-6)
        for prim in collision_primitives(jvrc1.urdf_path):
            if prim.link in (f"{S}_ANKLE_P_S", f"{s}_sole"):
                F = data.oMf[jvrc1.pin_model.getFrameId(prim.link)]
                lowest = (prim.local_points() @ F.rotation.T + F.translation)[:, 2].min()
                assert lowest >= M.translation[2] - 1e-9
        # The sole box lies on the sole plane.
        sole_box = next(p for p in collision_primitives(jvrc1.urdf_path) if p.link == f"{s}_sole")
        assert sole_box.local_points()[:, 2].min() == pytest.approx(0.0, abs=1e-9)


def test_sole_boxes_are_200_by_80_mm(jvrc1):
    for s, _ in SIDES:
        length, width = sole_size(jvrc1, f"{s}_sole")
        assert length == pytest.approx(0.200, abs=0.005)
        assert width == pytest.approx(0.080, abs=0.005)


def test_sole_rectangle_comes_from_the_flat_faces_of_the_foot_mesh(derived):
    _, _, _, soles = derived
    for sole in soles.values():
        # ~30-40 mm ahead of the ankle, on the mesh's lowest plane ~108 mm below it.
        assert 0.025 < sole.centre[0] < 0.045 and abs(sole.centre[1]) < 1e-3
        assert sole.centre[2] == pytest.approx(-0.1077, abs=5e-4)


def test_tcp_frames_between_thumb_and_fingers(jvrc1):
    """z out of the palm along the straight fingers, y along the line on which they close."""
    model, data = jvrc1.pin_model, jvrc1.create_data()
    q = jvrc1.default_q()
    base = np.array([0, 0, 1.0, 0, 0, 0, 1.0])
    pin.framesForwardKinematics(model, data, jvrc1.to_pin_q(base, q))
    for s, S in SIDES:
        tcp = data.oMf[jvrc1.frame_id(f"{s}_tcp")]
        wrist = data.oMf[model.getFrameId(f"{S}_WRIST_Y_S")]
        thumb = data.oMf[model.getFrameId(f"{S}_UTHUMB_S")].translation
        index = data.oMf[model.getFrameId(f"{S}_UINDEX_S")].translation
        little = data.oMf[model.getFrameId(f"{S}_ULITTLE_S")].translation
        fingers = (index + little) / 2
        # Approach: from the palm (wrist) towards the fingers.
        assert np.dot(tcp.rotation[:, 2], tcp.translation - wrist.translation) > 0.1
        assert np.dot(tcp.rotation[:, 2], -wrist.rotation[:, 2]) == pytest.approx(1.0)
        # Closing line: across the approach axis, thumb to fingers is along the TCP y axis
        # (the thumb is hinged 18 mm higher than the fingers, hence the z component).
        d = tcp.rotation.T @ (thumb - fingers)
        assert abs(d[0]) < 1e-9 and abs(d[1]) > 0.02
        # Midway between them across the closing line.
        t, f, c = (np.dot(v, tcp.rotation[:, 1]) for v in (thumb, fingers, tcp.translation))
        assert min(t, f) < c < max(t, f)


# ---------------------------------------------------------------- gripper and mimics


def test_finger_joints_follow_the_jaw_through_their_mimic(jvrc1):
    model = jvrc1.pin_model
    assert len(jvrc1.mimic) == 12
    rng = np.random.default_rng(3)
    base = np.array([0, 0, 1.0, 0, 0, 0, 1.0])
    for s, S in SIDES:
        jaw = jvrc1.joint_index(f"{S}_JAW")
        for value in (0.0, jvrc1.upper[jaw], rng.uniform(0, jvrc1.upper[jaw])):
            q = jvrc1.default_q()
            q[jaw] = value
            qp = jvrc1.to_pin_q(base, q)
            for name, (master, mult, off) in jvrc1.mimic.items():
                if not name.startswith(S + "_"):
                    continue
                assert master == f"{S}_JAW"
                jid = model.getJointId(name)
                angle = qp[model.idx_qs[jid]]
                assert angle == pytest.approx(mult * value + off, abs=1e-12)
                # The finger stays within the package's limits over the jaw's range.
                assert model.lowerPositionLimit[model.idx_qs[jid]] - 1e-5 <= angle
                assert angle <= model.upperPositionLimit[model.idx_qs[jid]] + 1e-5
        # Open jaw = straight fingers (the package's open hand).
        q = jvrc1.default_q()
        q[jaw] = jvrc1.upper[jaw]
        qp = jvrc1.to_pin_q(base, q)
        assert qp[model.idx_qs[model.getJointId(f"{S}_UTHUMB")]] == pytest.approx(0.0, abs=1e-5)


def test_gripper_spec_matches_the_jaw_joint(jvrc1):
    for side, arm in jvrc1.spec.arms.items():
        i = jvrc1.joint_index(arm.gripper.joint)
        assert arm.gripper.opening_per_unit * jvrc1.upper[i] == pytest.approx(arm.gripper.max_opening_m)
        assert jvrc1.lower[i] == 0.0


def test_jaw_opening_closes_to_zero_where_the_fingers_meet(derived):
    _, _, grips, _ = derived
    for grip in grips.values():
        assert grip.max_opening_m == pytest.approx(0.011, abs=1e-3)
        # Fingers straight at the open end, a few degrees of thumb travel to close.
        assert grip.open_angle == 0.0
        assert 0.02 < abs(grip.closed_angle) < 0.2


# ---------------------------------------------------------------- downstream, model-agnostic


def test_batch_com_and_frames_agree_with_pinocchio(jvrc1):
    rng = np.random.default_rng(7)
    Q = rng.uniform(jvrc1.lower, jvrc1.upper, size=(16, jvrc1.nq))
    base = np.array([0.1, -0.2, 0.8, 0.0, 0.0, np.sin(0.3), np.cos(0.3)])
    com, frames = BatchKinematics(jvrc1).com_and_frames(base, Q, ["l_tcp", "r_sole"])
    data = jvrc1.create_data()
    for i in range(len(Q)):
        assert np.abs(center_of_mass(jvrc1, data, base, Q[i]) - com[i]).max() < 1e-9
        tcp, sole = frame_poses(jvrc1, data, base, Q[i], ["l_tcp", "r_sole"])
        assert np.abs(tcp.translation - frames["l_tcp"][1][i]).max() < 1e-9
        assert np.abs(sole.rotation - frames["r_sole"][0][i]).max() < 1e-9


@pytest.mark.parametrize("name", BUILTIN_STANCES)
def test_stances_put_the_soles_on_the_ground_within_1mm(jvrc1, jvrc1_stances, name):
    st = jvrc1_stances[name]
    data = jvrc1.create_data()
    for foot in st.feet:
        (M,) = frame_poses(jvrc1, data, st.base_pose, st.q, [foot.frame])
        assert np.abs(M.translation - np.array(foot.pose[:3])).max() < 1e-3
        length, width = sole_size(jvrc1, foot.frame)
        assert abs(M.rotation[2, 0]) * length / 2 < 1e-3 and abs(M.rotation[2, 1]) * width / 2 < 1e-3
    assert np.all(st.q >= jvrc1.lower - 1e-12) and np.all(st.q <= jvrc1.upper + 1e-12)


def test_one_legged_cannot_hold_a_60mm_threshold(jvrc1_stances):
    st = jvrc1_stances["one-legged"]
    assert st.polygon.inradius == pytest.approx(0.042, abs=1e-3)
    assert st.polygon.inradius < 0.06
    assert st.margin == pytest.approx(st.polygon.inradius, abs=1e-3)  # CoM above the sole centre


def test_one_legged_60mm_scenario_is_reported_not_crashed(tmp_path):
    from service.cli.main import cli

    doc = (
        "schema: regrasp.scenario/1\nname: jvrc1-one-leg\nrobot: jvrc1\nstance: one-legged\n"
        "object: {shape: box, size: [0.01, 0.05, 0.2], mass_kg: 1}\n"
        "start_pose: [0.45, -0.2, 0.85, 0, 0, 0, 1]\ngoal_pose: [0.45, 0.2, 0.85, 0, 0, 0, 1]\n"
        "tables: [{name: t, pose: [0.55, 0, 0.375, 0, 0, 0, 1], size: [0.4, 1.2, 0.75]}]\nthreshold_m: 0.06\n"
    )
    path = tmp_path / "one-leg.yaml"
    path.write_text(doc)
    res = CliRunner().invoke(cli, ["scenario", "check", str(path)])
    assert res.exit_code == 1, res.output
    assert "larger than the support polygon's inradius 42.0 mm" in res.output


def test_unreachable_pelvis_height_names_the_foot(jvrc1):
    sdef = StanceDef(name="tall", feet=[
        {"frame": "r_sole", "pose": [0, -0.095, 0, 0, 0, 0, 1]},
        {"frame": "l_sole", "pose": [0, 0.095, 0, 0, 0, 0, 1]},
    ], pelvis_height_m=0.95)
    with pytest.raises(StanceError, match=r"foot r_sole cannot reach its placement; it stays \d+\.\d mm short"):
        solve_stance(jvrc1, sdef)


def test_cli_robot_list_urdf_and_info(jvrc1):
    from service.cli.main import cli

    runner = CliRunner()
    res = runner.invoke(cli, ["robot", "list"], catch_exceptions=False)
    assert res.exit_code == 0 and "jvrc1" in res.output
    res = runner.invoke(cli, ["robot", "urdf", "jvrc1"], catch_exceptions=False)
    assert Path(res.output.strip()) == urdf_path("jvrc1")
    res = runner.invoke(cli, ["robot", "info", "jvrc1", "--json"], catch_exceptions=False)
    assert res.exit_code == 0
    doc = json.loads(res.output)
    assert doc["name"] == "jvrc1" and doc["total_mass_kg"] == pytest.approx(62.4)
    assert 1.6 < doc["height_m"] < 1.8
    assert doc["joint_names"] == list(jvrc1.joint_names)
    assert set(doc["acceleration_limits"]) == set(jvrc1.joint_names)
    assert [s["name"] for s in doc["stances"]] == list(BUILTIN_STANCES)
    for s in doc["stances"]:
        assert "error" not in s
        assert len(s["base_pose"]) == 7 and len(s["q"]) == jvrc1.nq
