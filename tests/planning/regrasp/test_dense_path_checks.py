"""The timed path is checked at every sample, its search-planned segments too: a straight segment whose ends are
valid but which passes through the table between them cannot be timed into a plan unnoticed, and the quicker
replanned motions the timing substitutes are collision-free at every sample."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from planner import forking
from planner.motion.timing import time_parameterize
from planner.motion.topp import SplinePath
from planner.regrasp.plan_assembly import assemble, object_states
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.regrasp.timing.settings import PlanTimingSettings


def _collides(task, Q, hold, free_object) -> np.ndarray:
    checker = PlanTimer(task, PlanTimingSettings(), 1.0, task.threshold_m, 0.005).checker
    ok, _ = checker.validity(hold, free_object, None, active=None)(Q)
    return ~ok


def _grazing_plan(task, pieces):
    """The plan with one planned transit replaced by the straight segment between its ends, which the search would
    never have accepted (it hits something between the ends), laid out as if it were the search's own path."""
    for k, (piece, _, hold, current) in enumerate(object_states(pieces, task.evaluator, task.placements[task.start_id])):
        P = np.asarray(piece.path if piece.path is not None else [], dtype=float)
        if piece.kind != "transit" or len(P) <= 2:
            continue
        f = np.linspace(0.0, 1.0, 400)[:, None]
        line = P[0] * (1 - f) + P[-1] * f
        if not _collides(task, line, hold, current).any():
            continue
        _, Q = time_parameterize(P[[0, -1]], task.robot, task.settings.timing)
        assert not _collides(task, Q[:: max(1, len(Q) // 3)], hold, current)[[0, -1]].any()  # its ends are valid
        out = list(pieces)
        out[k] = replace(piece, path=P[[0, -1]], waypoints=Q)
        return out, k
    pytest.skip("no planned transit whose straight line collides in this task")


def test_a_segment_through_an_obstacle_between_checked_states_is_refused(solved):
    task, pieces = solved
    grazing, k = _grazing_plan(task, pieces)
    # trusting the search's own segments (as the timing once did) times the bad segment into the plan unnoticed
    trusted = PlanTimer(task, PlanTimingSettings(trust_search_segments=True, replans=0), 1.0, task.threshold_m,
                        0.005).time_plan(grazing)
    assert trusted.stats["dense_failures"] == []
    # checked at every sample, it is found: the run is not blended through it, and the plan's stats name it
    dense = PlanTimer(task, PlanTimingSettings(replans=0), 1.0, task.threshold_m, 0.005).time_plan(grazing)
    assert dense.stats["dense_failures"], "a segment through an obstacle passed the dense checks"
    assert "transit" in " ".join(dense.stats["dense_failures"])


def test_the_replanned_quicker_motions_are_collision_free_at_every_sample(solved):
    task, pieces = solved
    timing = PlanTimer(task, PlanTimingSettings(replans=3), 1.0, task.threshold_m, 0.005).time_plan(pieces)
    assert timing.stats["replans"] > 0 and timing.stats["dense_failures"] == []
    traj = assemble(timing.pieces, task.evaluator, 0.005, task.placements[task.start_id])
    for seg in traj.segments:
        if seg["kind"] != "transit":
            continue
        rows = np.arange(seg["first"], seg["last"] + 1)
        res = task.world.check_batch(task.stance.base_pose, traj.Q[rows], free_object_pose=traj.object_pose[rows])
        assert not res.collides.any(), f"transit collides at sample {rows[np.argmax(res.collides)]}"


def test_a_run_that_fails_off_its_blends_is_refused_before_it_is_timed(solved, monkeypatch):
    """The blended path of a run is checked before TOPP-RA times it: a run through an obstacle costs no timing at
    all (it used to be timed, sampled and checked first, once per alternative)."""
    task, pieces = solved
    grazing, k = _grazing_plan(task, pieces)
    timed_runs = []
    original = PlanTimer.time_part

    def time_part(self, run, W, blends, spline=None):
        timed_runs.append([id(p) for p in run.pieces])
        return original(self, run, W, blends, spline)

    monkeypatch.setattr(PlanTimer, "time_part", time_part)
    monkeypatch.setattr(forking, "spare_cores", lambda: 0)  # no helper: every run is timed where it is counted
    dense = PlanTimer(task, PlanTimingSettings(replans=0), 1.0, task.threshold_m, 0.005).time_plan(grazing)
    assert any("off the blends" in why for why in dense.stats["refused"])
    assert timed_runs, "no run was timed at all"
    assert not any(id(grazing[k]) in run for run in timed_runs), "the run through the obstacle was timed before it was refused"
    # without the check of the path before timing, the same run is timed first and refused after
    timed_runs.clear()
    PlanTimer(task, PlanTimingSettings(replans=0, path_check_rad=0.0), 1.0, task.threshold_m, 0.005).time_plan(grazing)
    assert any(id(grazing[k]) in run for run in timed_runs)


def test_a_refused_runs_spline_is_checked_once_not_pulled_towards_the_failing_path(solved, monkeypatch):
    """A run whose blended path fails away from its corners is refused, and its spline gets one check: the rounds
    that pull a failing spline towards the corners bring it nearer that same failing polyline, so none is spent."""
    task, pieces = solved
    grazing, k = _grazing_plan(task, pieces)
    spline_checks, invalid_s = Counter(), PlanTimer._invalid_s

    def counted(self, run, path, starts, s, Q):
        bad = invalid_s(self, run, path, starts, s, Q)
        if isinstance(path, SplinePath) and any(p is grazing[k] for p in run.pieces):
            spline_checks[id(run), bool(bad.size)] += 1
        return bad

    monkeypatch.setattr(PlanTimer, "_invalid_s", counted)
    monkeypatch.setattr(forking, "spare_cores", lambda: 0)  # no helper: every check is counted here
    dense = PlanTimer(task, PlanTimingSettings(replans=0), 1.0, task.threshold_m, 0.005).time_plan(grazing)
    assert any("off the blends" in why for why in dense.stats["refused"])
    assert spline_checks and all(n == 1 for n in spline_checks.values()), spline_checks
    assert all(failed for _, failed in spline_checks)  # its one check failed: the rounds would have been spent
