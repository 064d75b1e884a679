"""Static joint torques and grip: against pinocchio's RNEA with the same contact forces, and by hand."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner.stability.effort import GRAVITY, EffortEvaluator, GripLimits, effort_limits, effort_table

COM_LOCAL = np.array([0.04, -0.02, 0.08])


def _rnea_torques(robot, stance, q, holding, T_tcp_obj, mass, ev):
    """RNEA at rest with the object's weight through the TCP(s) and the evaluator's contact wrenches as fext."""
    model, data = robot.pin_model, robot.pin_model.createData()
    qp = robot.to_pin_q(stance.base_pose, q)
    pin.framesForwardKinematics(model, data, qp)
    fext = [pin.Force.Zero() for _ in range(model.njoints)]
    sides = {"none": (), "left": ("left",), "right": ("right",), "both": ("left", "right")}[holding]
    c_obj = np.zeros(3)
    if sides:
        carrier = "left" if holding == "both" else holding
        T = data.oMf[robot.frame_id(robot.spec.arms[carrier].tcp)].homogeneous @ T_tcp_obj
        c_obj = T[:3, :3] @ COM_LOCAL + T[:3, 3]
        for s in sides:
            jid = model.frames[robot.frame_id(robot.spec.arms[s].tcp)].parentJoint
            f = pin.Force(np.array([0.0, 0.0, -GRAVITY * mass / len(sides)]), np.zeros(3))
            fext[jid] += data.oMi[jid].actInv(pin.SE3(np.eye(3), c_obj).act(f))
    M = pin.computeTotalMass(model)
    m = mass if sides else 0.0
    com = (M * pin.centerOfMass(model, data, qp, False) + m * c_obj) / (M + m)
    W = ev.contact_wrenches(com, M + m)[0]
    for c, (jid, pt) in enumerate(zip(ev.contact_joint, ev.contact_point)):
        jid = int(jid)
        fext[jid] += data.oMi[jid].actInv(pin.SE3(np.eye(3), pt).act(pin.Force(W[c, :3], W[c, 3:])))
    tau = pin.rnea(model, data, qp, np.zeros(model.nv), np.zeros(model.nv), fext)
    return tau, np.array([tau[model.idx_vs[model.getJointId(n)]] for n in ev.table.checked])


@pytest.mark.parametrize("stance_name", ["upright", "one-legged", "crouched", "staggered"])
@pytest.mark.parametrize("holding", ["none", "right", "both"])
def test_torques_match_pinocchio_rnea_with_the_same_contact_forces(hrp5p, stances, stance_name, holding):
    stance = stances[stance_name]
    ev = EffortEvaluator(hrp5p, stance, 12.0, COM_LOCAL)
    rng = np.random.default_rng(7)
    Q = np.repeat(stance.q[None], 6, axis=0)
    moving = np.concatenate([hrp5p.waist_indices(), hrp5p.arm_indices("left"), hrp5p.arm_indices("right")])
    Q[:, moving] += rng.uniform(-0.4, 0.4, (6, moving.size))
    Q = np.clip(Q, hrp5p.lower, hrp5p.upper)
    T_tcp_obj = np.eye(4)
    T_tcp_obj[:3, 3] = [0.0, 0.03, 0.06]
    res = ev.evaluate(Q, holding, T_tcp_obj=T_tcp_obj)
    for i in range(len(Q)):
        tau, expected = _rnea_torques(hrp5p, stance, Q[i], holding, T_tcp_obj, 12.0, ev)
        assert np.abs(tau[:6]).max() < 1e-6  # the contact wrenches balance the floating base
        np.testing.assert_allclose(res.torque[i], expected, atol=1e-6, rtol=0)
        assert res.effort_ratio[i] == pytest.approx(np.max(np.abs(expected) / ev.table.limit), abs=1e-9)


def test_contact_wrenches_are_the_minimum_norm_balance(hrp5p, stances):
    """Two soles: the wrenches balance the weight and no other balancing set has a smaller norm."""
    stance = stances["staggered"]
    ev = EffortEvaluator(hrp5p, stance, 0.0, np.zeros(3))
    com = np.array([0.02, 0.01, 0.9])
    W = ev.contact_wrenches(com, 100.0)[0].ravel()
    A = np.zeros((6, 12))
    for c, pt in enumerate(ev.contact_point):
        A[:3, 6 * c:6 * c + 3] = np.eye(3)
        A[3:, 6 * c:6 * c + 3] = pin.skew(pt)
        A[3:, 6 * c + 3:6 * c + 6] = np.eye(3)
    b = np.r_[0.0, 0.0, 100.0 * GRAVITY, np.cross(com, [0.0, 0.0, 100.0 * GRAVITY])]
    np.testing.assert_allclose(A @ W, b, atol=1e-9)
    null = np.linalg.svd(A)[2][6:]  # directions that keep the balance
    rng = np.random.default_rng(0)
    for _ in range(20):
        other = W + null.T @ rng.normal(size=6)
        assert np.linalg.norm(other) >= np.linalg.norm(W) - 1e-9


@settings(max_examples=15, deadline=None, suppress_health_check=list(HealthCheck))
@given(offset=st.lists(st.floats(-0.15, 0.15), min_size=3, max_size=3), mass=st.floats(0.5, 30.0),
       holding=st.sampled_from(["left", "right", "both"]))
def test_grip_ratio_is_the_weight_and_its_moment_about_the_closing_axis(hrp5p, stances, offset, mass, holding):
    stance = stances["upright"]
    grip = GripLimits(friction=0.5, force_n=200.0, patch_radius_m=0.015)
    ev = EffortEvaluator(hrp5p, stance, mass, np.zeros(3), grip={"left": grip, "right": grip})
    T_tcp_obj = np.eye(4)
    T_tcp_obj[:3, 3] = offset
    q = stance.q.copy()
    res = ev.evaluate(q[None], holding, T_tcp_obj=T_tcp_obj)
    data = hrp5p.create_data()
    pin.framesForwardKinematics(hrp5p.pin_model, data, hrp5p.to_pin_q(stance.base_pose, q))
    carrier = "left" if holding == "both" else holding
    T_obj = data.oMf[hrp5p.frame_id(hrp5p.spec.arms[carrier].tcp)].homogeneous @ T_tcp_obj
    c = T_obj[:3, 3]
    hands = ("left", "right") if holding == "both" else (holding,)
    share = mass * GRAVITY / len(hands)
    worst = 0.0
    for side in hands:
        T = data.oMf[hrp5p.frame_id(hrp5p.spec.arms[side].tcp)]
        about = abs(np.cross(c - T.translation, [0.0, 0.0, -share]) @ T.rotation[:, 1])
        worst = max(worst, share / (2 * 0.5 * 200.0), about / (2 * 0.5 * 200.0 * 0.015))
    assert res.grip_ratio[0] == pytest.approx(worst, rel=1e-9, abs=1e-12)


def test_rigid_hands_and_empty_hands_have_no_grip_load(hrp5p, stances):
    stance = stances["upright"]
    ev = EffortEvaluator(hrp5p, stance, 50.0, np.zeros(3), grip={"left": None, "right": None})
    assert ev.evaluate(stance.q[None], "left", T_tcp_obj=np.eye(4)).grip_ratio[0] == 0.0
    ev = EffortEvaluator(hrp5p, stance, 50.0, np.zeros(3))
    assert ev.evaluate(stance.q[None], "none").grip_ratio[0] == 0.0


def test_limits_come_from_the_spec_over_the_urdf_and_leave_the_jaws_out(hrp5p):
    limits = effort_limits(hrp5p)
    assert "LJAW" not in limits and "RJAW" not in limits
    assert limits["RKP"] == hrp5p.spec.effort_limits["RKP"] == 500.0
    assert set(effort_table(hrp5p).limit_source.values()) == {"spec effort_limits"}


def test_paper_payload_static_torques_are_within_hrp5p_limits_and_a_heavy_one_is_not(hrp5p, stances):
    """15 kg held in one hand in front of the body (the paper's heaviest task) is within the limits;
    the same grasp with 100 kg is over them (arms hanging: a short lever)."""
    stance = stances["crouched"]
    T_tcp_obj = np.eye(4)
    T_tcp_obj[:3, 3] = [0.0, 0.0, 0.05]
    light = EffortEvaluator(hrp5p, stance, 15.0, np.zeros(3)).evaluate(stance.q[None], "right", T_tcp_obj=T_tcp_obj)
    heavy = EffortEvaluator(hrp5p, stance, 100.0, np.zeros(3)).evaluate(stance.q[None], "right", T_tcp_obj=T_tcp_obj)
    assert light.effort_ratio[0] < 1.0 < heavy.effort_ratio[0]
