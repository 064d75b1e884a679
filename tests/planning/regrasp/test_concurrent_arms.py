"""Both arms at once around a handover: the merged path does each arm's own motion at its own pace, takes the time
of the longer one (not their sum) at the velocity limits, and is made only of two arms' motions that can share it;
a merge of a slower path than the best-ranked one is kept only where it is quicker than that path with the arms one
after the other; a handover plan timed with it is quicker, rests where the hands change what they hold, and passes
the independent plan checker and the safety gate."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from plan_checker import check_plan

from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.motion.smoothing import path_length
from planner.regrasp.timing.concurrent_arms import LEADS, both_at_once, may_merge, merged_pieces
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.regrasp.timing.settings import PlanTimingSettings
from planner.regrasp.plan_assembly import MotionPiece
from planner.regrasp.timing.runs import off_path
from planner.regrasp.settings import PlannerSettings
from planner.robot.model import load_robot
from planner.scene.scenarios import load_scenario
from planner.stability.evaluator import HoldSpec
from robot_bridge.gate import SafetyGate

DATA = Path(__file__).resolve().parents[2] / "data"
N = 7
A_JOINTS, B_JOINTS = [0, 1, 2], [4, 5]  # joint 3 and 6 move in neither: both leave them where they are


def _paths(seed: int, ka: int, kb: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    start = rng.uniform(-1.0, 1.0, N)
    A = np.repeat(start[None], ka, axis=0)
    A[1:, A_JOINTS] += np.cumsum(rng.uniform(-0.6, 0.6, (ka - 1, len(A_JOINTS))), axis=0)
    B = np.repeat(A[-1:], kb, axis=0)
    B[1:, B_JOINTS] += np.cumsum(rng.uniform(-0.6, 0.6, (kb - 1, len(B_JOINTS))), axis=0)
    return A, B, rng.uniform(0.5, 2.0, N)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), ka=st.integers(2, 6), kb=st.integers(2, 6), lead=st.floats(0.0, 1.0))
def test_each_arm_follows_its_own_path_and_the_pair_takes_the_longer_ones_time(seed, ka, kb, lead):
    A, B, w = _paths(seed, ka, kb)
    P = both_at_once(A, B, w, lead)
    assert np.array_equal(P[0], A[0]) and np.array_equal(P[-1], B[-1])
    # each arm's joints go along its own polyline (the merged waypoints lie on it), the others never move
    assert not off_path(P[:, A_JOINTS], A[:, A_JOINTS], tol=1e-9).any()
    assert not off_path(P[:, B_JOINTS], B[:, B_JOINTS], tol=1e-9).any()
    assert np.array_equal(P[:, [3, 6]], np.repeat(A[:1, [3, 6]], len(P), axis=0))
    # each at its own pace: at the velocity limits the pair takes the longer of A and (B after its lead), never
    # the sum (lead 1: one after the other)
    ta, tb = path_length(A, w), path_length(B, w)
    assert path_length(P, w) == pytest.approx(max(ta, lead * ta + tb), rel=1e-9, abs=1e-12)
    # B starts only once A has had its lead
    moved_b = np.abs(P[:, B_JOINTS] - A[-1, B_JOINTS]).max(axis=1) > 0
    elapsed = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(P, axis=0) * w).max(axis=1))])
    if moved_b.any():
        assert elapsed[np.argmax(moved_b)] >= lead * ta - 1e-9


def _piece(kind, hand, path, holding="right"):
    hold = None if holding == "none" else HoldSpec(holding, np.eye(4))
    return MotionPiece(kind, hand, path, holding, hold, path=path)


def test_only_two_arms_motions_that_share_no_joint_and_hold_the_object_alike_are_merged():
    A, B, w = _paths(1, 3, 3)
    carry, reach = _piece("transfer", "right", A), _piece("transit", "left", B)
    assert may_merge(carry, reach)
    merged = merged_pieces([carry, reach, _piece("approach", "left", B[-1:].repeat(2, axis=0))], w, 0.0)
    assert [(p.kind, p.hand) for p in merged] == [("transfer", "both"), ("approach", "left")]
    assert np.array_equal(merged[0].path, both_at_once(A, B, w, 0.0))
    same_arm = _piece("transit", "right", B)
    shared = B.copy()
    shared[1:, 0] += 0.1  # B moves one of A's joints too
    assert not may_merge(carry, same_arm)
    assert not may_merge(carry, _piece("transit", "left", shared))
    assert not may_merge(_piece("transit", "right", A, "none"), _piece("transit", "left", B, "none"))
    assert not may_merge(carry, _piece("approach", "left", B))
    assert merged_pieces([carry, same_arm], w, 0.0) is None


@pytest.mark.slow
def test_a_handover_plan_moves_both_arms_at_once_and_passes_the_checker_and_the_gate():
    scenario = load_scenario(DATA / "small-box.yaml")
    options = PlanOptions(hands="right-left")
    plan = plan_scenario(scenario, options)
    base = PlannerSettings()
    apart = plan_scenario(scenario, options, settings=base.model_copy(
        update={"plan_timing": base.plan_timing.model_copy(update={"concurrent_arms": False})}))
    assert plan["status"] == apart["status"] == "solved"
    assert plan["stats"]["timing"]["merged_runs"] >= 1 and apart["stats"]["timing"]["merged_runs"] == 0
    assert plan["timing"]["duration_s"] < apart["timing"]["duration_s"]
    Q = np.array([p["q"] for p in plan["trajectory"]])
    robot = load_robot(plan["robot"]["name"])
    arms = {side: robot.arm_indices(side) for side in ("left", "right")}
    both = [s for s in plan["segments"] if s["kind"] == "transfer" and s["hand"] == "both"]
    assert both
    for seg in both:  # both arms move within it
        rows = Q[seg["first"]: seg["last"] + 1]
        assert all(np.ptp(rows[:, arms[side]], axis=0).max() > 1e-3 for side in arms)
    holding = [p["holding"] for p in plan["trajectory"]]
    for i in range(1, len(holding)):  # rests where the hands change what they hold
        if holding[i] != holding[i - 1]:
            assert np.array_equal(Q[i - 1], Q[i]) and np.array_equal(Q[i], Q[i + 1])
    assert check_plan(plan).errors == []
    verdict = SafetyGate().check(plan, offline=True)
    assert verdict.passed, verdict.message


class _Timings(PlanTimer):
    """A plan timer whose runs' timings are given (``durations[i]``: try i's duration, None where its samples fail
    the checks), to test which try is kept apart from the timing itself. The first ``of_best`` merged tries are
    merges of the first one-arm try (the best-ranked path), at the first leads."""

    def __init__(self, durations: list[float | None], merged: int, of_best: int):
        robot = SimpleNamespace(velocity_limit=np.ones(N), acceleration_limit=np.ones(N))
        task = SimpleNamespace(robot=robot, limits=None, constrained=True, evaluator=SimpleNamespace(threshold_m=0.05))
        super().__init__(task, PlanTimingSettings(), 1.0, 0.05, 0.005)
        self.tries = [SimpleNamespace(index=i) for i in range(len(durations))]
        for j in range(of_best):
            self._merged[(id(self.tries[merged]), LEADS[j])] = self.tries[j]
        self.durations = durations
        self.timed: list[int] = []

    def time_run(self, run):
        self.timed.append(run.index)
        d = self.durations[run.index]
        return None if d is None else ([np.zeros((2, N))], d, d)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.none(), st.floats(0.5, 10.0)), min_size=1, max_size=12).flatmap(
    lambda d: st.tuples(st.just(d), st.integers(0, len(d) - 1))).flatmap(
    lambda dm: st.tuples(st.just(dm[0]), st.just(dm[1]), st.integers(0, min(dm[1], len(LEADS))))))
def test_a_merge_of_a_slower_path_is_kept_only_where_it_is_quicker_than_the_best_path_one_arm_after_the_other(case):
    durations, merged, of_best = case
    timer = _Timings(durations, merged, of_best)
    k, timed, (merged_refused, alone_refused) = timer._kept_try(timer.tries, merged)
    first_merged = next((i for i in range(merged) if durations[i] is not None), None)
    first_alone = next((i for i in range(merged, len(durations)) if durations[i] is not None), None)
    timed_merged = set(range(first_merged + 1 if first_merged is not None else merged))
    timed_alone = set(range(merged, (first_alone + 1) if first_alone is not None else len(durations)))
    if first_merged is None and first_alone is None:
        assert timed is None and merged_refused == merged
        return
    assert timed is not None and timed[2] == durations[k]
    assert merged_refused == (first_merged if first_merged is not None else merged)
    if first_merged is None:  # no merge passed: the arms one after the other
        assert k == first_alone and alone_refused == first_alone - merged
        assert set(timer.timed) == timed_merged | timed_alone
    elif first_merged < of_best:  # a merge of the best-ranked path: kept, the one-arm tries never timed
        assert k == first_merged and alone_refused == 0
        assert set(timer.timed) == timed_merged
    else:  # a merge of a slower path: kept only where the best path one arm after the other is not quicker
        passed = [i for i in (first_merged, first_alone) if i is not None]
        assert durations[k] == min(durations[i] for i in passed)
        assert k == (first_alone if first_alone is not None and durations[first_alone] < durations[first_merged]
                     else first_merged)
        assert alone_refused == (k - merged if k >= merged else 0)
        assert set(timer.timed) == timed_merged | timed_alone
