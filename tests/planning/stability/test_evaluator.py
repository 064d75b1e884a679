"""StateEvaluator against an independent recomputation (pinocchio + shapely), and eq. 1 properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.kinematics.reduced import ReducedKinematics
from planner.stability.evaluator import HoldSpec, StateEvaluator
from tests.planning.conftest import COM_LOCAL


def _random_states(robot, base_q, active, n, seed):
    rng = np.random.default_rng(seed)
    Q = np.repeat(base_q[None], n, axis=0)
    Q[:, active] = rng.uniform(robot.lower[active], robot.upper[active], (n, len(active)))
    return Q


def test_batch_matches_independent_recomputation(robot, evaluator, hold_right, right_active, independent):
    Q = _random_states(robot, evaluator.stance.q, right_active, 25, seed=1)
    batch = evaluator.evaluate(Q, hold_right, active=right_active)
    for i, q in enumerate(Q):
        assert np.allclose(batch.com[i], independent.system_com(q, hold_right), atol=1e-9)
        assert batch.margin[i] == pytest.approx(independent.margin(q, hold_right), abs=1e-9)
        assert batch.stable[i] == (independent.margin(q, hold_right) >= 0.03)


def test_detected_active_columns_and_single_path_agree(robot, evaluator, hold_right, right_active):
    Q = _random_states(robot, evaluator.stance.q, right_active, 12, seed=2)
    auto = evaluator.evaluate(Q, hold_right)
    given_ = evaluator.evaluate(Q, hold_right, active=right_active)
    assert np.allclose(auto.com, given_.com, atol=1e-12)
    for i, q in enumerate(Q):
        one = evaluator.evaluate_one(q, hold_right)
        assert np.allclose(one.com, auto.com[i], atol=1e-12)
        assert np.allclose(one.object_pose, auto.object_pose[i], atol=1e-12)
        assert one.stable == bool(auto.stable[i])


def test_object_pose_follows_the_tcp(robot, evaluator, hold_right, right_active):
    Q = _random_states(robot, evaluator.stance.q, right_active, 5, seed=3)
    batch = evaluator.evaluate(Q, hold_right, active=right_active)
    for i, q in enumerate(Q):
        T_tcp = evaluator.tcp_pose(q, "right")
        assert np.allclose(batch.object_pose[i] @ hold_right.T_obj_tcp, T_tcp, atol=1e-12)


def test_reduced_kinematics_with_every_joint_active(robot, upright, independent):
    rng = np.random.default_rng(4)
    Q = rng.uniform(robot.lower, robot.upper, (6, robot.nq))
    rk = ReducedKinematics(robot, upright.base_pose, Q[0], np.arange(robot.nq))
    com = rk.com(Q)
    for i in range(len(Q)):
        assert np.allclose(com[i], independent.system_com(Q[i], None), atol=1e-9)


def test_no_hold_means_robot_com_only(evaluator, upright):
    one = evaluator.evaluate_one(upright.q, None)
    assert one.object_pose is None
    assert np.allclose(one.com, upright.robot_com, atol=1e-12)


def test_bad_inputs_are_named(robot, upright):
    with pytest.raises(ValueError, match="object_mass"):
        StateEvaluator(robot, upright, 0.03, -1.0, COM_LOCAL)
    with pytest.raises(ValueError, match="threshold_m"):
        StateEvaluator(robot, upright, float("nan"), 1.0, COM_LOCAL)
    with pytest.raises(ValueError, match="side"):
        HoldSpec("middle", np.eye(4))
    with pytest.raises(ValueError, match="rotation"):
        HoldSpec("left", np.diag([2.0, 1.0, 1.0, 1.0]))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), t1=st.floats(0.0, 0.1), t2=st.floats(0.0, 0.1))
def test_raising_the_threshold_never_makes_a_state_stable(robot, evaluator, hold_right, right_active, seed, t1, t2):
    lo, hi = sorted((t1, t2))
    Q = _random_states(robot, evaluator.stance.q, right_active, 20, seed)
    low = evaluator.evaluate(Q, hold_right, active=right_active, threshold_m=lo).stable
    high = evaluator.evaluate(Q, hold_right, active=right_active, threshold_m=hi).stable
    assert not np.any(high & ~low)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), m1=st.floats(0.1, 20.0), m2=st.floats(0.1, 20.0))
def test_heavier_object_moves_com_towards_object_com_as_eq1(robot, upright, hold_right, right_active, seed, m1, m2):
    Q = _random_states(robot, upright.q, right_active, 8, seed)
    e1 = StateEvaluator(robot, upright, 0.03, m1, COM_LOCAL).evaluate(Q, hold_right, active=right_active)
    e2 = StateEvaluator(robot, upright, 0.03, m2, COM_LOCAL).evaluate(Q, hold_right, active=right_active)
    T = e1.object_pose
    c_obj = np.einsum("nij,j->ni", T[:, :3, :3], COM_LOCAL) + T[:, :3, 3]
    M = robot.total_mass
    # Eq. 1: c(m) - c_obj = M / (M + m) * (c_robot - c_obj), so the two offsets are parallel with a known ratio.
    expected = (M + m1) / (M + m2)
    assert np.allclose(e2.com - c_obj, expected * (e1.com - c_obj), atol=1e-12)
    if m2 > m1:
        assert np.all(np.linalg.norm(e2.com - c_obj, axis=1) <= np.linalg.norm(e1.com - c_obj, axis=1) + 1e-12)


def test_second_model_with_mimic_fingers():
    """Nothing is specific to one model: JVRC-1 (finger mimic joints with multipliers) is exact too."""
    from planner.robot.model import load_robot
    from planner.stability.robot_com import robot_com as center_of_mass
    from planner.stability.stances import solve_stance

    robot = load_robot("jvrc1")
    stance = solve_stance(robot, "upright")
    rng = np.random.default_rng(0)
    Q = rng.uniform(robot.lower, robot.upper, (20, robot.nq))
    rk = ReducedKinematics(robot, stance.base_pose, Q[0], np.arange(robot.nq))
    data = robot.create_data()
    com = rk.com(Q)
    for i in range(len(Q)):
        assert np.allclose(com[i], center_of_mass(robot, data, stance.base_pose, Q[i]), atol=1e-9)


def test_active_columns_must_cover_what_varies(robot, evaluator, right_active):
    Q = _random_states(robot, evaluator.stance.q, right_active, 20, seed=5)
    Q[3, robot.arm_indices("left")[0]] += 0.1
    with pytest.raises(ValueError, match="outside 'active'"):
        evaluator.evaluate(Q, None, active=right_active)


def test_results_do_not_depend_on_which_batch_came_first(robot, evaluator, hold_right, right_active):
    """Two evaluators see the same batch after different ones: every bit of the CoM and margin agrees.

    A reduced tree is cached per active set and fixed values; were it built from whichever batch
    came first, the folded composite bodies (and so the last bits of every CoM) would depend on
    the evaluation order, and a plan whose motions are shared with a forked helper would differ
    from the serial one."""
    first = _random_states(robot, evaluator.stance.q, right_active, 40, seed=3)
    later = _random_states(robot, evaluator.stance.q, right_active, 40, seed=4)
    warmed = evaluator.with_threshold(evaluator.threshold_m)
    warmed.evaluate(first, hold_right, active=right_active)
    fresh = evaluator.with_threshold(evaluator.threshold_m)
    a = warmed.evaluate(later, hold_right, active=right_active)
    b = fresh.evaluate(later, hold_right, active=right_active)
    assert np.array_equal(a.com, b.com) and np.array_equal(a.margin, b.margin)
    assert np.array_equal(a.object_pose, b.object_pose)
