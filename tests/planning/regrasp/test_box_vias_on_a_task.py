"""Joint-space box vias (planner/motion/time_box_vias.py) on a real motion: the one-legged task's transit home with
the right hand (right-right), where the straight line sweeps the hand through the table's edge and the search's path
takes 2.7 times the line's time at the velocity limits. The box vias go round the edge in little more than the line's
time, every state passes the task's own checks, and the plan's timing takes them up."""

from __future__ import annotations

import numpy as np
import pytest

from planner.motion.interpolation import edge_states
from planner.motion.smoothing import path_length
from planner.motion.time_box_vias import BoxViaSettings, box_via_paths


@pytest.fixture(scope="module")
def transit_home():
    """The one-legged task (right-right), its search's last planned motion (the hand's way home) and that motion's
    validity as the plan's timing checks it."""
    from planner.jobs.plan_job import build_task
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.plan_assembly import object_states
    from planner.regrasp.timing.plan_timer import PlanTimer
    from planner.regrasp.timing.settings import PlanTimingSettings
    from planner.scene.scenarios import load_builtin

    task = build_task(load_builtin("one-legged"))
    res = HandConfigPlanner(task, "right-right").plan()
    assert res.status == "solved"
    timer = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005)
    states = list(object_states(res.pieces, task.evaluator, task.placements[task.start_id]))
    k, (piece, _, hold, resting) = [(k, s) for k, s in enumerate(states)
                                    if s[0].path is not None and len(s[0].path) > 2][-1]
    assert hold is None and piece.kind == "transit" and piece.hand == "right"
    validity = timer.checker.validity(None, resting, None, active=None)
    return task, timer, k, np.asarray(piece.path, dtype=float), validity, 1.0 / timer.vlim


def test_the_box_vias_go_round_the_table_in_little_more_than_the_lines_time(transit_home):
    task, _, _, own, validity, weights = transit_home
    a, b = own[0], own[-1]
    assert not validity(edge_states(a, b, 0.005))[0].all(), "the straight line must be blocked for this test to mean it"
    line = path_length(np.vstack([a, b]), weights)
    assert path_length(own, weights) > 2.0 * line
    s = BoxViaSettings()
    robot = task.robot
    found = box_via_paths(a, b, validity, np.random.default_rng(5), weights, robot.lower, robot.upper, 0.005, s)
    assert found
    for W in found:
        assert np.array_equal(W[0], a) and np.array_equal(W[-1], b)
        dense = np.vstack([edge_states(p, q, 0.005) for p, q in zip(W[:-1], W[1:])])
        assert validity(dense)[0].all()  # every state, rechecked here, passes the task's checks
        assert set(np.flatnonzero(np.ptp(W, axis=0) > 0)) <= set(np.flatnonzero(b != a))  # only the motion's joints
        assert path_length(W, weights) <= (1 + max(s.slacks)) * line + 1e-9


def test_the_plans_timing_takes_the_box_vias_up_where_its_own_paths_are_slow(transit_home):
    """The timing's candidates for the motion include the box vias' paths (drawn from the motion's own stream) and
    its quickest path is much quicker at the velocity limits than the search's."""
    _, timer, k, own, validity, weights = transit_home
    found = timer._box_via_paths(k, own, [own], validity, weights)
    assert found and timer.stats["box_via_paths"] == len(found)
    assert min(path_length(W, weights) for W in found) < 0.6 * path_length(own, weights)
    # where a path already found is within min_ratio of the line, none are drawn
    straight = np.vstack([own[0], own[-1]])
    assert timer._box_via_paths(k, own, [own, straight], validity, weights) == []
