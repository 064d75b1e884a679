"""Timing within the limits, at rest at both ends, ZMP inside the polygon; shortcut smoothing stays valid."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point, Polygon

from planner.motion.smoothing import path_length, shortcut
from planner.motion.timing import TimingSettings, time_parameterize, time_path
from planner.motion.trrt import plan_motion

DT = 0.005
G = 9.81


def _waypoints(robot, upright, active, deltas):
    W = np.repeat(upright.q[None], len(deltas) + 1, axis=0)
    for k, d in enumerate(deltas, start=1):
        W[k, active] = W[k - 1, active] + d
    return np.clip(W, robot.lower, robot.upper)


def _check_limits(robot, Q):
    v = np.diff(Q, axis=0) / DT
    a = np.diff(Q, 2, axis=0) / DT**2
    assert np.all(np.abs(v) <= robot.velocity_limit * (1 + 1e-9))
    assert np.all(np.abs(a) <= robot.acceleration_limit * (1 + 1e-9))
    assert np.all(Q >= robot.lower - 1e-12) and np.all(Q <= robot.upper + 1e-12)


def test_limits_rest_and_uniform_period(robot, upright, right_active):
    W = _waypoints(robot, upright, right_active, [0.6, -0.9, 0.2])
    t, Q = time_parameterize(W, robot)
    assert np.allclose(np.diff(t), DT)
    _check_limits(robot, Q)
    assert np.array_equal(Q[0], W[0]) and np.array_equal(Q[-1], W[-1])
    assert np.array_equal(Q[0], Q[1]) and np.array_equal(Q[-1], Q[-2])  # exactly zero velocity at both ends
    for w in W:  # every waypoint is a sample (rest-to-rest segments)
        assert np.min(np.abs(Q - w).max(axis=1)) < 1e-12


def test_samples_stay_on_the_straight_segments(robot, upright, right_active):
    W = _waypoints(robot, upright, right_active, [0.5, -0.3])
    _, Q = time_parameterize(W, robot)
    # Each sample is W[i] + s (W[i+1] - W[i]) with s in [0, 1] for its segment.
    for q in Q:
        ok = False
        for a, b in zip(W[:-1], W[1:]):
            s = float(np.dot(q - a, b - a) / np.dot(b - a, b - a))
            if -1e-12 <= s <= 1 + 1e-12 and np.allclose(a + s * (b - a), q, atol=1e-12):
                ok = True
        assert ok


def test_zmp_kept_inside_with_a_heavy_object(robot, upright, right_active, hold_right):
    from planner.stability.evaluator import StateEvaluator

    ev = StateEvaluator(robot, upright, 0.0, 8.0, np.array([0.15, 0.08, 0.15]))
    # A fast swing whose full-speed ZMP leaves the polygon while its static margin stays >= 1 cm.
    for deltas in ([0.5, -1.0], [0.4, -0.8], [-0.5, 0.5], [0.6, -0.6], [-0.6, 0.9], [0.8, -0.4]):
        W = _waypoints(robot, upright, right_active, deltas)
        fast = time_path(W, robot, ev, hold_right, TimingSettings(max_slowdowns=0, zmp_min_margin_m=0.0))
        if fast.min_zmp_margin_m < 0.0 and fast.margin.min() >= 0.01:
            break
    else:
        pytest.fail("no candidate swing leaves the polygon at full speed")
    slow = time_path(W, robot, ev, hold_right)
    assert slow.ok, slow.reason
    assert slow.t[-1] > fast.t[-1]
    _check_limits(robot, slow.Q)
    # Independent ZMP: CoM from the evaluator's batch recomputed by central differences, margin by shapely.
    com = np.array([ev.evaluate_one(q, hold_right).com for q in slow.Q])
    acc = (com[2:, :2] - 2 * com[1:-1, :2] + com[:-2, :2]) / DT**2
    zmp = com[1:-1, :2] - com[1:-1, 2:3] / G * acc
    poly = Polygon(upright.polygon.vertices)
    assert all(poly.contains(Point(*z)) for z in zmp)
    assert slow.min_zmp_margin_m >= slow.stats["zmp_required_m"] - 1e-9


def test_static_margin_failure_is_explained(robot, upright, right_active, hold_right):
    from planner.stability.evaluator import StateEvaluator

    ev = StateEvaluator(robot, upright, 0.03, 40.0, np.array([0.15, 0.08, 0.15]))
    W = _waypoints(robot, upright, right_active, [0.8])
    res = time_path(W, robot, ev, hold_right)
    assert not res.ok and res.reason


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(1, 4))
def test_limits_hold_for_random_paths(robot, upright, right_active, seed, k):
    rng = np.random.default_rng(seed)
    W = _waypoints(robot, upright, right_active, [rng.uniform(-0.6, 0.6, len(right_active)) for _ in range(k)])
    _, Q = time_parameterize(W, robot, TimingSettings(rest_samples=0))
    _check_limits(robot, Q)
    v_end = np.abs(Q[-1] - Q[-2]) / DT
    assert np.all(v_end <= robot.acceleration_limit * DT)  # the profile ends at rest: last step ~ a dt / 2


def test_shortcut_is_shorter_valid_and_deterministic(robot, upright, evaluator, hold_right, right_active, independent):
    start = upright.q.copy()
    goal = start.copy()
    goal[right_active] = np.clip([0.1, 0.0, 0.5, 0.2, -0.6, -0.5, 0.3, -1.2, 0.3, 0.2, 0.1, 0.0], robot.lower[right_active], robot.upper[right_active])
    mid = 0.5 * (start[right_active] + goal[right_active])

    def validity(Q):
        b = evaluator.evaluate(Q, hold_right, active=right_active)
        return b.stable & (np.linalg.norm(Q[:, right_active] - mid, axis=1) >= 0.4), b.margin

    res = plan_motion(start, goal, right_active, validity, robot.lower, robot.upper, np.random.default_rng(1))
    assert res.ok
    a = shortcut(res.path, validity, np.random.default_rng(2))
    b = shortcut(res.path, validity, np.random.default_rng(2))
    assert np.array_equal(a.path, b.path)
    assert a.length_before == pytest.approx(path_length(res.path))
    assert a.length_after <= a.length_before + 1e-12
    assert np.array_equal(a.path[0], start) and np.array_equal(a.path[-1], goal)
    for p, q in zip(a.path[:-1], a.path[1:]):
        n = max(1, int(np.ceil(np.abs(q - p).max() / 0.02)))
        for s in np.linspace(0, 1, n + 1):
            x = p + s * (q - p)
            assert independent.margin(x, hold_right) >= 0.03 - 1e-12
            assert np.linalg.norm(x[right_active] - mid) >= 0.4
