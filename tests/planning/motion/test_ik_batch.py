"""The batched IK reaches what pinocchio's descent reaches, within tolerance and limits, the one-hand
solver gives its results, and a target's solution does not depend on the other targets of its batch."""

from __future__ import annotations

import numpy as np
import pytest

from planner.kinematics.batch import BatchKinematics
from planner.motion.ik import IkSettings, IkSolver
from planner.motion.ik_batch import BatchIk


@pytest.fixture(scope="module")
def arm_ik(robot, upright):
    return IkSolver(robot, upright, IkSettings(use_waist=False, restarts=0))


@pytest.fixture(scope="module")
def batch_ik(robot, arm_ik):
    return BatchIk(robot, BatchKinematics(robot), arm_ik.settings)


def _targets(robot, arm_ik, upright, side, n, seed, spread=0.5):
    rng = np.random.default_rng(seed)
    act = arm_ik.active_indices([side])
    Q = np.repeat(upright.q[None], n, axis=0)
    Q[:, act] = np.clip(upright.q[act] + rng.normal(0.0, spread, (n, len(act))), robot.lower[act], robot.upper[act])
    return np.array([arm_ik.tcp_pose(q, side) for q in Q])


@pytest.mark.parametrize("side", ["left", "right"])
def test_solutions_reach_their_targets_within_the_limits(robot, upright, arm_ik, batch_ik, side):
    T = _targets(robot, arm_ik, upright, side, 60, seed=3)
    res = batch_ik.solve(side, T, upright.base_pose, upright.q, upright.q)
    assert res.ok.mean() >= 0.9, f"only {res.ok.mean():.0%} of reachable targets reached"
    act = batch_ik.active_columns(side)
    for q, target in zip(res.q[res.ok], T[res.ok]):
        reached = arm_ik.tcp_pose(q, side)  # pinocchio, not the batch's own kinematics
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) <= arm_ik.settings.pos_tol_m
        c = (np.trace(reached[:3, :3].T @ target[:3, :3]) - 1.0) / 2.0
        assert np.arccos(np.clip(c, -1.0, 1.0)) <= arm_ik.settings.rot_tol_rad
        assert np.all(q[act] >= robot.lower[act]) and np.all(q[act] <= robot.upper[act])
        moved = np.flatnonzero(q != upright.q)
        assert set(moved.tolist()) <= set(act.tolist())


def test_it_succeeds_where_pinocchios_local_descent_does(robot, upright, arm_ik, batch_ik):
    """The same rules (seed, damping, rest pull, step cap, limits, stall rule) in pinocchio's LOCAL
    log6 errors and Jacobians (the solver's two-hand attempt, an independent implementation): the
    outcomes agree, though the iterates differ."""
    import pinocchio as pin

    T = _targets(robot, arm_ik, upright, "right", 80, seed=4, spread=0.8)
    res = batch_ik.solve("right", T, upright.base_pose, upright.q, upright.q)
    active = arm_ik.active_indices(["right"])
    vcols = np.array([arm_ik._vcol[robot.joint_names[i]] for i in active])
    local = np.array([arm_ik._attempt(upright.q, upright.q, {"right": pin.SE3(t[:3, :3], t[:3, 3])}, ["right"], active, vcols)[4]
                      for t in T])
    assert np.mean(res.ok == local) >= 0.9, (res.ok.sum(), local.sum())
    assert np.array_equal(res.ok, [arm_ik.solve_arm("right", t, upright.q, np.random.default_rng(0)).ok for t in T])


def test_a_target_is_solved_the_same_whatever_else_is_in_the_batch(robot, upright, arm_ik, batch_ik):
    T = _targets(robot, arm_ik, upright, "left", 12, seed=5)
    together = batch_ik.solve("left", T, upright.base_pose, upright.q, upright.q)
    for k in (0, 5, 11):
        alone = batch_ik.solve("left", T[k:k + 1], upright.base_pose, upright.q, upright.q)
        assert alone.ok[0] == together.ok[k]
        assert np.array_equal(alone.q[0], together.q[k])


def test_out_of_reach_and_per_target_seeds(robot, upright, arm_ik, batch_ik):
    T = _targets(robot, arm_ik, upright, "right", 3, seed=6)
    far = T[0].copy()
    far[:3, 3] += [1.5, 0.0, 0.0]
    seeds = np.repeat(upright.q[None], 4, axis=0)
    act = batch_ik.active_columns("right")
    seeds[1, act] = np.clip(seeds[1, act] + 0.3, robot.lower[act], robot.upper[act])
    res = batch_ik.solve("right", np.array([far, *T]), upright.base_pose, seeds, upright.q)
    assert not res.ok[0]
    assert res.ok[1:].all()
    assert res.iterations.max() <= arm_ik.settings.max_iterations + 1
