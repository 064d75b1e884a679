"""Paths through task-space via postures (planner/motion/task_space_vias.py) on the upright task's first transit:
the hand goes from beside the thigh to above the object, and the straight joint-space line between those postures
sweeps it through the table's edge. The via paths go round it, every state passes the task's own checks, and they
are much quicker than the search's own path."""

from __future__ import annotations

import numpy as np
import pytest

from planner.motion.interpolation import edge_states
from planner.motion.smoothing import path_length
from planner.motion.task_space_vias import ViaSettings, via_paths


@pytest.fixture(scope="module")
def first_transit():
    """The upright task (right-right), its search's first planned motion and that motion's validity as the plan's
    timing checks it (the object resting on the table)."""
    from planner.jobs.plan_job import build_task
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.plan_assembly import object_states
    from planner.regrasp.timing.plan_timer import PlanTimer
    from planner.regrasp.timing.settings import PlanTimingSettings
    from planner.scene.scenarios import load_builtin

    task = build_task(load_builtin("upright"))
    res = HandConfigPlanner(task, "right-right").plan()
    assert res.status == "solved"
    timer = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
    piece, _, hold, resting = next(s for s in object_states(res.pieces, task.evaluator, task.placements[task.start_id])
                                   if s[0].path is not None and len(s[0].path) > 2)
    assert hold is None and piece.kind == "transit" and piece.hand == "right"
    validity = timer.checker.validity(None, resting, None, active=None)
    return task, np.asarray(piece.path, dtype=float), validity, 1.0 / timer.vlim


def test_the_via_paths_go_round_the_table_and_are_quicker_than_the_searchs_path(first_transit):
    task, own, validity, weights = first_transit
    a, b = own[0], own[-1]
    line = edge_states(a, b, 0.005)
    assert not validity(line)[0].all(), "the straight line must be blocked for this test to mean anything"
    found = via_paths(a, b, "right", task.ik, validity, np.random.default_rng(3), weights, 0.005)
    assert 1 <= len(found) <= ViaSettings().keep
    times = [path_length(W, weights) for W in found]
    assert times == sorted(times)
    for W in found:
        assert np.array_equal(W[0], a) and np.array_equal(W[-1], b) and len(W) in (3, 4)
        # every state, rechecked here at the resolution asked for, passes the task's checks
        dense = np.vstack([edge_states(p, q, 0.005) for p, q in zip(W[:-1], W[1:])])
        assert validity(dense)[0].all()
        assert np.abs(np.diff(dense, axis=0)).max() <= 0.005 + 1e-12
        # only the waist and the right arm move
        moved = np.flatnonzero(np.ptp(W, axis=0) > 0)
        assert set(moved) <= set(task.ik.active_indices(["right"]))
    # the line's own time is the floor; the quickest via path is close to it and far below the search's path
    assert path_length(np.vstack([a, b]), weights) <= times[0] < 0.6 * path_length(own, weights)


def test_the_via_paths_are_the_generators(first_transit):
    task, own, validity, weights = first_transit
    a, b = own[0], own[-1]
    first, second = (via_paths(a, b, "right", task.ik, validity, np.random.default_rng(11), weights, 0.005)
                     for _ in range(2))
    assert len(first) == len(second) and all(np.array_equal(p, q) for p, q in zip(first, second))


def test_a_candidate_budget_of_none_or_nothing_kept_gives_no_path(first_transit):
    task, own, validity, weights = first_transit
    rng = np.random.default_rng(0)
    for settings in (ViaSettings(keep=0), ViaSettings(checked=0)):
        assert via_paths(own[0], own[-1], "right", task.ik, validity, rng, weights, 0.005, settings) == []
    # with a single via each and no pairs, every path has one via
    singles = via_paths(own[0], own[-1], "right", task.ik, validity, rng, weights, 0.005, ViaSettings(pairs=False))
    assert all(len(W) == 3 for W in singles)


def test_the_grid_and_the_samples_each_find_a_way_round(first_transit):
    """The grid alone and the random samples alone both find a valid path here; a hand position outside the box
    the samples are drawn from is never a via's."""
    task, own, validity, weights = first_transit
    a, b = own[0], own[-1]
    grid = via_paths(a, b, "right", task.ik, validity, np.random.default_rng(2), weights, 0.005,
                     ViaSettings(samples=0))
    sampled = ViaSettings(fractions=(0.2, 0.8), reach=(), rise_m=(), samples=40)
    drawn = via_paths(a, b, "right", task.ik, validity, np.random.default_rng(2), weights, 0.005, sampled)
    assert grid and drawn
    ends = np.array([task.ik.tcp_pose(a, "right")[:3, 3], task.ik.tcp_pose(b, "right")[:3, 3]])
    low = ends.min(axis=0) - np.asarray(sampled.sample_below_m) - 1e-3  # the IK's 1 mm tolerance
    high = ends.max(axis=0) + np.asarray(sampled.sample_above_m) + 1e-3
    for W in drawn:
        for q in W[1:-1]:
            p = task.ik.tcp_pose(q, "right")[:3, 3]
            assert np.all(p >= low) and np.all(p <= high), p


@pytest.mark.parametrize("bad", [dict(fractions=(0.0,)), dict(fractions=(1.0,)), dict(reach=(float("nan"),)),
                                 dict(rise_m=(-0.01,)), dict(checked=-1), dict(keep=-1), dict(samples=-1),
                                 dict(sample_below_m=(0.1, 0.1)), dict(sample_above_m=(0.1, -0.1, 0.1))])
def test_bad_via_settings_are_refused(bad):
    with pytest.raises(ValueError):
        ViaSettings(**bad)
