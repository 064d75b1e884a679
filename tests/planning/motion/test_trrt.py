"""T-RRT: valid paths (recomputed independently), determinism, cancel, and the survey's exploration counts."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from planner.motion.trrt import TrrtSettings, plan_motion
from planner.survey.counting import ExploreLeg, explore_counted
from planner.termination import Termination

RESOLUTION = 0.02


@pytest.fixture(scope="module")
def task(robot, upright, evaluator, hold_right, right_active):
    start = upright.q.copy()
    # A goal that is stable with the object (the first of a few candidates, so posture changes don't break the test).
    for cand in ([0.1, 0.0, 0.5, 0.2, -0.6, -0.5, 0.3, -1.2, 0.3, 0.2, 0.1, 0.0],
                 [0.0, 0.0, 0.6, 0.0, -0.4, -0.3, 0.2, -1.0, 0.0, 0.0, 0.0, 0.0],
                 [0.05, 0.0, -0.5, 0.1, -0.5, -0.4, 0.0, -1.4, 0.2, 0.0, 0.0, 0.3]):
        goal = upright.q.copy()
        goal[right_active] = np.clip(cand, robot.lower[right_active], robot.upper[right_active])
        if evaluator.evaluate(np.vstack([start, goal]), hold_right).stable.all():
            break
    else:
        pytest.fail("no stable goal candidate")
    mid = 0.5 * (start[right_active] + goal[right_active])

    def validity(Q):
        b = evaluator.evaluate(Q, hold_right, active=right_active)
        blocked = np.linalg.norm(Q[:, right_active] - mid, axis=1) < 0.4  # an obstacle on the straight line
        return b.stable & ~blocked, b.margin

    return start, goal, mid, validity


def _dense(path, resolution=RESOLUTION):
    out = [path[0]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.abs(b - a).max() / resolution - 1e-9)))
        out += [a + (k / n) * (b - a) for k in range(1, n + 1)]
    return np.array(out)


def test_path_found_around_an_obstacle_and_every_state_is_valid(robot, task, right_active, hold_right, independent):
    start, goal, mid, validity = task
    res = plan_motion(start, goal, right_active, validity, robot.lower, robot.upper, np.random.default_rng(0))
    assert res.ok, res.reason
    assert np.array_equal(res.path[0], start) and np.array_equal(res.path[-1], goal)
    dense = _dense(res.path)
    for q in dense:
        assert independent.margin(q, hold_right) >= 0.03 - 1e-12
        assert np.linalg.norm(q[right_active] - mid) >= 0.4
        assert np.all(q >= robot.lower) and np.all(q <= robot.upper)
    fixed = np.setdiff1d(np.arange(robot.nq), right_active)
    assert np.all(dense[:, fixed] == start[fixed])


def test_same_seed_same_path(robot, task, right_active):
    start, goal, _, validity = task
    a = plan_motion(start, goal, right_active, validity, robot.lower, robot.upper, np.random.default_rng(7))
    b = plan_motion(start, goal, right_active, validity, robot.lower, robot.upper, np.random.default_rng(7))
    assert a.ok and np.array_equal(a.path, b.path)


def test_invalid_goal_and_bad_input_are_reported(robot, task, right_active, upright):
    start, goal, mid, validity = task
    bad_goal = start.copy()
    bad_goal[right_active] = mid
    res = plan_motion(start, bad_goal, right_active, validity, robot.lower, robot.upper, np.random.default_rng(0))
    assert res.status == "invalid_goal" and res.path is None
    other = start.copy()
    other[robot.arm_indices("left")[0]] += 0.1  # differs in a joint that is not active
    res = plan_motion(start, other, right_active, validity, robot.lower, robot.upper, np.random.default_rng(0))
    assert res.status == "bad_input" and "not active" in res.reason


@pytest.mark.host_pauses(limit_s=0.2)
def test_iteration_cap_and_cancel(robot, task, right_active):
    start, goal, mid, _ = task

    def walled(Q):  # the goal is enclosed: no path exists
        near_goal = np.linalg.norm(Q[:, right_active] - goal[right_active], axis=1)
        ok = (near_goal < 0.05) | (near_goal > 0.3)
        return ok, np.zeros(len(Q))

    capped = plan_motion(start, goal, right_active, walled, robot.lower, robot.upper, np.random.default_rng(0), TrrtSettings(max_iterations=20))
    assert capped.status == "iteration_cap" and capped.stats["rounds"] == 20

    stop = threading.Event()
    timer = threading.Timer(0.2, stop.set)
    timer.start()
    t0 = time.perf_counter()
    res = plan_motion(start, goal, right_active, walled, robot.lower, robot.upper, np.random.default_rng(0),
                      termination=Termination(10**7, 30.0, stop.is_set))
    elapsed = time.perf_counter() - t0
    timer.cancel()
    assert res.status == "canceled"
    assert elapsed < 1.2  # cancel lands within 1 s of the request at 0.2 s

    stop.set()  # a cancel that arrives before the start
    res = plan_motion(start, goal, right_active, walled, robot.lower, robot.upper, np.random.default_rng(0),
                      termination=Termination(10**7, canceled=stop.is_set))
    assert res.status == "canceled"

    # The user's own time budget ends the search as a timeout, and says how far it got.
    res = plan_motion(start, goal, right_active, walled, robot.lower, robot.upper, np.random.default_rng(0),
                      termination=Termination(10**7, 0.3))
    assert res.status == "timeout" and res.stats["rounds"] > 0 and f"after {res.stats['rounds']} rounds" in res.reason


def test_margin_cost_biases_towards_stability(robot, upright, evaluator, hold_right, right_active):
    """The energy-based trees sample poses of a larger mean margin than a flat-cost RRT of the same seed."""
    start = upright.q.copy()
    goal = start.copy()
    goal[right_active] = np.clip(start[right_active] + 0.5, robot.lower[right_active], robot.upper[right_active])

    def validity(Q):
        b = evaluator.evaluate(Q, hold_right, active=right_active)
        return b.stable, b.margin

    means = {}
    for cost in (True, False):
        ex = explore_counted([ExploreLeg(start, goal, hold_right, right_active)], evaluator, np.random.default_rng(3),
                             budget=3000, trrt=TrrtSettings(margin_cost=cost))
        means[cost] = ex.margin.mean()
    assert means[True] > means[False]


def test_exploration_aims_a_share_of_its_samples_at_the_other_end(robot, upright, right_active):
    """Goal bias (the paper's start/end bias): each tree grows from one end of the leg, and a
    ``goal_bias`` share of its samples is the other tree's root; the rest are uniform."""
    from planner.motion.trrt import TreeSearch

    start = upright.q.copy()
    goal = start.copy()
    goal[right_active] = np.clip(start[right_active] - 0.6, robot.lower[right_active], robot.upper[right_active])

    def aimed_share(bias: float) -> float:
        s = TrrtSettings(goal_bias=bias)
        search = TreeSearch(start, goal, right_active, robot.lower, robot.upper, 0.1, 0.1, s)
        search.batch_size = 4000
        aimed = 0
        proposals = search.propose(np.random.default_rng(5))
        for ti, near, new, _ in proposals:
            x, root = search.trees[ti].nodes[near], search.trees[ti ^ 1].nodes[0]
            step, to_root = new - x, root - x
            cos = step @ to_root / (np.linalg.norm(step) * np.linalg.norm(to_root))
            aimed += cos > 1 - 1e-9
        return aimed / len(proposals)

    assert aimed_share(1.0) == 1.0 and aimed_share(0.0) == 0.0
    assert aimed_share(TrrtSettings().goal_bias) == pytest.approx(TrrtSettings().goal_bias, abs=0.02)


from hypothesis import given  # noqa: E402
from hypothesis import settings as hsettings
from hypothesis import strategies as st


@hsettings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), spread=st.floats(0.1, 1.0))
def test_plan_is_valid_or_a_named_failure(robot, upright, evaluator, hold_right, right_active, independent, seed, spread):
    rng = np.random.default_rng(seed)
    start = upright.q.copy()
    goal = start.copy()
    goal[right_active] = np.clip(start[right_active] + rng.uniform(-spread, spread, len(right_active)),
                                 robot.lower[right_active], robot.upper[right_active])

    def validity(Q):
        b = evaluator.evaluate(Q, hold_right, active=right_active)
        return b.stable, b.margin

    res = plan_motion(start, goal, right_active, validity, robot.lower, robot.upper, rng, TrrtSettings(max_iterations=60))
    assert res.status in ("solved", "iteration_cap", "invalid_goal")
    if res.ok:
        for q in _dense(res.path)[:: 7]:
            assert independent.margin(q, hold_right) >= 0.03 - 1e-12
    else:
        assert res.reason and res.path is None


@hsettings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), size=st.integers(1, 300), dim=st.integers(1, 14), copies=st.integers(0, 5))
def test_the_nearest_node_is_the_first_of_the_closest(seed, size, dim, copies):
    """The compiled nearest-node search picks numpy's argmin of the squared distances, ties (repeated nodes)
    going to the first, and sums each distance as numpy does, to the bit."""
    from planner.compiled.nearest_kernels import _numpy_sum
    from planner.motion.trrt import _Tree

    rng = np.random.default_rng(seed)
    nodes = rng.uniform(-2, 2, (size, dim))
    if copies and size > 1:
        nodes[rng.integers(1, size, copies)] = nodes[rng.integers(0, size)]
    tree = _Tree(nodes[0], 0.0, capacity=4)
    for x in nodes[1:]:
        tree.add(x, 0, 0.0)
    for q in list(rng.uniform(-2, 2, (5, dim))) + [nodes[rng.integers(0, size)]]:
        d2 = ((nodes - q) ** 2).sum(axis=1)
        i, dist = tree.nearest(q)
        assert i == int(np.argmin(d2)) == int(np.flatnonzero(d2 == d2.min())[0]) and dist == np.sqrt(d2.min())
        assert all(_numpy_sum((row - q) ** 2) == s for row, s in zip(nodes, d2))
