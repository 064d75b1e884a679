"""The generated HRP-5P model: figures, frames, regeneration, and the batch CoM path."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from planner.kinematics.batch import BatchKinematics
from planner.robot import hrp5p_urdf
from planner.robot.info import standing_height
from planner.stability.robot_com import robot_com as center_of_mass
from planner.robot.model import (
    UnknownNameError,
    frame_poses,
    load_robot,
)
from planner.robot.registry import UnknownRobotError, urdf_path


def test_regenerating_gives_the_committed_urdf():
    assert hrp5p_urdf.generate() == hrp5p_urdf.URDF_PATH.read_text()


def test_mass_height_and_joint_count(hrp5p):
    assert hrp5p.total_mass == pytest.approx(101.0, abs=1e-6)
    assert standing_height(hrp5p) == pytest.approx(1.82, abs=0.005)
    assert hrp5p.nq == 37
    body = [j for j in hrp5p.joint_names if not j.endswith("JAW")]
    assert len(body) == 35
    for prefix in ("R", "L"):
        for name in ("CY", "CR", "CP", "KP", "AP", "AR", "SC", "SP", "SR", "SY", "EP", "WRY", "WRR", "WRP", "HDY"):
            assert prefix + name in hrp5p.joint_names


def test_every_link_with_mass_has_positive_inertia(hrp5p):
    model = hrp5p.pin_model
    for jid in range(1, model.njoints):
        inertia = model.inertias[jid]
        if inertia.mass > 0:
            eig = np.linalg.eigvalsh(inertia.inertia)
            assert np.all(eig > 0), model.names[jid]


def test_contract_frames_and_sole_boxes(hrp5p, stances):
    st = stances["upright"]
    data = hrp5p.create_data()
    lsole, rsole, ltcp, rtcp = frame_poses(hrp5p, data, st.base_pose, st.q, ["l_sole", "r_sole", "l_tcp", "r_tcp"])
    for sole, y in ((lsole, 0.095), (rsole, -0.095)):
        assert sole.translation == pytest.approx([0.0, y, 0.0], abs=1e-3)
        assert sole.rotation[:, 2] == pytest.approx([0, 0, 1], abs=1e-3)
    # TCP: z is the approach direction out of the palm; with arms hanging it points down-forward.
    assert rtcp.rotation[2, 2] < 0 and ltcp.rotation[2, 2] < 0
    from planner.stability.stances import sole_size

    assert sole_size(hrp5p, "l_sole") == pytest.approx((0.23, 0.13))


def test_jaw_opens_0_to_82_mm_and_closes_along_the_tcp_y_axis(hrp5p, stances):
    """docs/contract.md section 1: the TCP sits midway between the jaws and its y axis is the closing direction."""
    import pinocchio as pin

    st = stances["upright"]
    model, data = hrp5p.pin_model, hrp5p.create_data()
    for side, jaw in (("r", "RJAW"), ("l", "LJAW")):
        k = hrp5p.joint_index(jaw)
        assert hrp5p.lower[k] == pytest.approx(0.0) and 2 * hrp5p.upper[k] == pytest.approx(0.082)
        q = st.q.copy()
        q[k] = hrp5p.upper[k]
        pin.framesForwardKinematics(model, data, hrp5p.to_pin_q(st.base_pose, q))
        tcp = data.oMf[hrp5p.frame_id(f"{side}_tcp")]
        a = data.oMf[model.getFrameId(f"{side.upper()}_FINGER_A_LINK")].translation
        b = data.oMf[model.getFrameId(f"{side.upper()}_FINGER_B_LINK")].translation
        d = tcp.rotation.T @ (a - b)  # finger to finger, in the TCP frame
        assert abs(d[0]) < 1e-9 and abs(d[2]) < 1e-9 and abs(abs(d[1]) - 0.082) < 0.03
        mid = tcp.rotation.T @ ((a + b) / 2 - tcp.translation)  # midway between the jaws: on the TCP z axis
        assert abs(mid[0]) < 1e-9 and abs(mid[1]) < 1e-9


def test_mimic_fingers_follow_the_jaw(hrp5p, stances):
    st = stances["upright"]
    q = st.q.copy()
    q[hrp5p.joint_index("RJAW")] = 0.03
    qp = hrp5p.to_pin_q(st.base_pose, q)
    model = hrp5p.pin_model
    a = qp[model.idx_qs[model.getJointId("RJAW")]]
    b = qp[model.idx_qs[model.getJointId("RJAW_MIMIC")]]
    assert a == b == pytest.approx(0.03)
    data = hrp5p.create_data()
    pin.framesForwardKinematics(model, data, qp)
    fa = data.oMf[model.getFrameId("R_FINGER_A_LINK")].translation
    fb = data.oMf[model.getFrameId("R_FINGER_B_LINK")].translation
    assert np.linalg.norm(fa - fb) == pytest.approx(0.06, abs=1e-9)  # opening = 2 x joint value


def test_velocity_and_acceleration_limits_present(hrp5p):
    assert np.all(hrp5p.velocity_limit > 0)
    assert np.all(hrp5p.acceleration_limit > 0)
    assert hrp5p.acceleration_limit[hrp5p.joint_index("RCP")] < hrp5p.acceleration_limit[hrp5p.joint_index("RSP")]


def test_batch_com_matches_pinocchio(hrp5p):
    rng = np.random.default_rng(3)
    Q = rng.uniform(hrp5p.lower, hrp5p.upper, size=(64, hrp5p.nq))
    quat = rng.normal(size=4)
    base = np.concatenate([rng.uniform(-1, 1, 3), quat / np.linalg.norm(quat)])
    com = BatchKinematics(hrp5p).com(base, Q)
    data = hrp5p.create_data()
    for i in range(len(Q)):
        assert np.abs(com[i] - center_of_mass(hrp5p, data, base, Q[i])).max() < 1e-9


def test_batch_frames_match_pinocchio(hrp5p):
    rng = np.random.default_rng(4)
    Q = rng.uniform(hrp5p.lower, hrp5p.upper, size=(8, hrp5p.nq))
    base = np.array([0.1, -0.2, 0.8, 0, 0, 0, 1.0])
    _, frames = BatchKinematics(hrp5p).com_and_frames(base, Q, ["l_tcp", "r_sole"])
    data = hrp5p.create_data()
    for i in range(len(Q)):
        ltcp, rsole = frame_poses(hrp5p, data, base, Q[i], ["l_tcp", "r_sole"])
        assert np.abs(frames["l_tcp"][1][i] - ltcp.translation).max() < 1e-9
        assert np.abs(frames["l_tcp"][0][i] - ltcp.rotation).max() < 1e-9
        assert np.abs(frames["r_sole"][1][i] - rsole.translation).max() < 1e-9


def test_batches_moving_one_arm_match_pinocchio(hrp5p):
    """Batches like the planner's (one arm moving, the rest fixed), repeated and with other fixed
    values: every frame exact."""
    rng = np.random.default_rng(5)
    base = np.array([0.0, 0.0, 0.85, 0, 0, 0, 1.0])
    kin = BatchKinematics(hrp5p)
    arm = hrp5p.arm_indices("left")
    ref = rng.uniform(hrp5p.lower, hrp5p.upper)
    data = hrp5p.create_data()
    for fixed in (ref, ref, rng.uniform(hrp5p.lower, hrp5p.upper)):
        n = 8
        Q = np.repeat(fixed[None], n, axis=0)
        Q[:, arm] = rng.uniform(hrp5p.lower[arm], hrp5p.upper[arm], size=(n, len(arm)))
        _, frames = kin.com_and_frames(base, Q, ["l_tcp", "r_tcp"])
        for i in range(len(Q)):
            ltcp, rtcp = frame_poses(hrp5p, data, base, Q[i], ["l_tcp", "r_tcp"])
            assert np.abs(frames["l_tcp"][1][i] - ltcp.translation).max() < 1e-9
            assert np.abs(frames["r_tcp"][1][i] - rtcp.translation).max() < 1e-9


@pytest.mark.parametrize("n", [1, 2, 7, 40])
def test_batches_of_any_size_match_pinocchio(hrp5p, n):
    """Random whole-body configurations, one or many per batch: CoM and frames agree with pinocchio."""
    rng = np.random.default_rng(6 + n)
    Q = rng.uniform(hrp5p.lower, hrp5p.upper, size=(n, hrp5p.nq))
    base = np.array([0.05, 0.1, 0.82, 0.0, 0.0, 0.3826834323650898, 0.9238795325112867])
    com, frames = BatchKinematics(hrp5p).com_and_frames(base, Q, ["l_tcp", "r_sole"])
    assert com.shape == (n, 3) and frames["l_tcp"][0].shape == (n, 3, 3)
    data = hrp5p.create_data()
    for i in range(n):
        assert np.abs(com[i] - center_of_mass(hrp5p, data, base, Q[i])).max() < 1e-9
        ltcp, rsole = frame_poses(hrp5p, data, base, Q[i], ["l_tcp", "r_sole"])
        assert np.abs(frames["l_tcp"][0][i] - ltcp.rotation).max() < 1e-9
        assert np.abs(frames["r_sole"][1][i] - rsole.translation).max() < 1e-9


def test_unknown_names_list_the_valid_ones(hrp5p):
    with pytest.raises(UnknownRobotError, match="valid robots: .*hrp5p"):
        load_robot("hrp6")
    with pytest.raises(UnknownNameError, match="valid joints: .*RCY"):
        hrp5p.joint_index("RKNEE")
    with pytest.raises(UnknownNameError, match="valid frames: .*r_tcp"):
        hrp5p.frame_id("r_palm")


def test_urdf_loads_with_a_free_flyer():
    model = pin.buildModelFromUrdf(str(urdf_path("hrp5p")), pin.JointModelFreeFlyer())
    assert model.names[1] == "root_joint"
    assert model.nq == 7 + 39  # 37 joints + 2 mimic fingers


def test_batch_fk_with_a_constant_subtree_matches_pinocchio(hrp5p, stances):
    """Legs, neck and the idle arm constant across the batch: computed once, broadcast, still exact."""
    st = stances["upright"]
    rng = np.random.default_rng(5)
    Q = np.repeat(st.q[None], 40, axis=0)
    arm = np.concatenate([hrp5p.waist_indices(), hrp5p.arm_indices("right")])
    Q[:, arm] = rng.uniform(hrp5p.lower[arm], hrp5p.upper[arm], size=(40, len(arm)))
    com, frames = BatchKinematics(hrp5p).com_and_frames(st.base_pose, Q, ["r_tcp", "l_tcp", "l_sole"])
    data = hrp5p.create_data()
    for i in range(0, 40, 7):
        assert np.abs(com[i] - center_of_mass(hrp5p, data, st.base_pose, Q[i])).max() < 1e-9
        rtcp, ltcp, lsole = frame_poses(hrp5p, data, st.base_pose, Q[i], ["r_tcp", "l_tcp", "l_sole"])
        assert np.abs(frames["r_tcp"][1][i] - rtcp.translation).max() < 1e-9
        assert np.abs(frames["l_tcp"][0][i] - ltcp.rotation).max() < 1e-9
        assert np.abs(frames["l_sole"][1][i] - lsole.translation).max() < 1e-9
