"""IK reaches reachable targets within tolerance and limits, and explains unreachable ones."""

from __future__ import annotations

import numpy as np
import pytest

from planner.motion.ik import IkSettings, IkSolver


@pytest.fixture(scope="module")
def ik(robot, upright):
    return IkSolver(robot, upright)


def _pose_error(T_a, T_b):
    dp = np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])
    c = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return dp, float(np.arccos(np.clip(c, -1.0, 1.0)))


def _reachable_target(robot, ik, upright, sides, rng, spread=0.5):
    q = upright.q.copy()
    act = ik.active_indices(sides)
    q[act] = np.clip(upright.q[act] + rng.normal(0.0, spread, len(act)), robot.lower[act], robot.upper[act])
    return {side: ik.tcp_pose(q, side) for side in sides}


@pytest.mark.parametrize("side", ["left", "right"])
def test_single_arm_reaches_random_reachable_targets(robot, upright, ik, side):
    rng = np.random.default_rng(10)
    for _ in range(8):
        targets = _reachable_target(robot, ik, upright, [side], rng)
        res = ik.solve_arm(side, targets[side], upright.q, rng)
        assert res.ok, res.reason
        dp, dr = _pose_error(ik.tcp_pose(res.q, side), targets[side])
        assert dp <= 1e-3 and dr <= 1e-2
        assert np.all(res.q >= robot.lower - 1e-12) and np.all(res.q <= robot.upper + 1e-12)
        # Only waist and this arm moved; legs, neck and the other arm kept the seed's values.
        moved = np.flatnonzero(np.abs(res.q - upright.q) > 0)
        assert set(moved) <= set(ik.active_indices([side]).tolist())


def test_dual_arm_handover_targets(robot, upright, ik):
    rng = np.random.default_rng(11)
    for _ in range(4):
        targets = _reachable_target(robot, ik, upright, ["left", "right"], rng, spread=0.3)
        res = ik.solve_both(targets["left"], targets["right"], upright.q, rng)
        assert res.ok, res.reason
        for side in ("left", "right"):
            dp, dr = _pose_error(ik.tcp_pose(res.q, side), targets[side])
            assert dp <= 1e-3 and dr <= 1e-2


def test_seeded_solution_is_deterministic(robot, upright, ik):
    targets = _reachable_target(robot, ik, upright, ["right"], np.random.default_rng(12))
    a = ik.solve_arm("right", targets["right"], upright.q, np.random.default_rng(5))
    b = ik.solve_arm("right", targets["right"], upright.q, np.random.default_rng(5))
    assert a.ok and np.array_equal(a.q, b.q)


def test_out_of_reach_target_returns_none_with_reason(robot, upright, ik):
    T = np.eye(4)
    T[:3, 3] = [2.0, -0.3, 1.0]
    res = ik.solve_arm("right", T, upright.q, np.random.default_rng(0))
    assert res.q is None and res.code == "OUT_OF_REACH" and "reach" in res.reason


def test_unreachable_target_within_the_reach_sphere_returns_no_convergence(robot, upright):
    """Behind the back on the other side: within the arm's reach sphere (so not OUT_OF_REACH), but no
    posture within the limits gets near it (none of 20,000 random ones comes within 6 cm)."""
    from planner.kinematics.batch import BatchKinematics

    solver = IkSolver(robot, upright, IkSettings(restarts=2))
    target = np.array([-0.4, 0.4, 0.9])
    active = solver.active_indices(["right"])
    Q = np.repeat(upright.q[None], 20000, axis=0)
    Q[:, active] = np.random.default_rng(1).uniform(robot.lower[active], robot.upper[active], (len(Q), len(active)))
    tcp = robot.spec.arms["right"].tcp
    _, frames = BatchKinematics(robot).com_and_frames(upright.base_pose, Q, [tcp])
    assert np.linalg.norm(frames[tcp][1] - target, axis=1).min() > 0.06
    T = np.eye(4)
    T[:3, 3] = target
    res = solver.solve_arm("right", T, upright.q, np.random.default_rng(0))
    assert res.q is None and res.code == "NO_CONVERGENCE" and "residual" in res.reason


def test_bad_input_is_reported(robot, upright, ik):
    res = ik.solve({"middle": np.eye(4)}, upright.q, np.random.default_rng(0))
    assert res.code == "BAD_INPUT"
    T = np.eye(4)
    T[0, 0] = np.nan
    assert ik.solve_arm("left", T, upright.q, np.random.default_rng(0)).code == "BAD_INPUT"


def test_key_pose_targets_back_off_along_the_approach():
    from planner.motion.ik import key_pose_targets

    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # approach (z) along world +x
    T[:3, 3] = [0.5, -0.2, 0.8]
    k = key_pose_targets(T, approach_m=0.05, lift_m=0.07)
    assert np.allclose(k["pregrasp"][:3, 3], [0.45, -0.2, 0.8])
    assert np.allclose(k["lift"][:3, 3], [0.5, -0.2, 0.87])
    assert np.allclose(k["grasp"], T) and np.allclose(k["pregrasp"][:3, :3], T[:3, :3])
