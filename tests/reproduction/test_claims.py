"""The paper report's claim checker (experiments/claims.py): strict verdicts on survey rows."""

from __future__ import annotations

from experiments.claims import (
    judge_all_stable,
    judge_best_stance,
    judge_no_removal,
    judge_ordering,
    judge_threshold_motion,
)


def row(hands, ratio, lo, hi):
    return {"hands": hands, "ratio": ratio, "ratio_ci95": [lo, hi], "stable": 1, "unstable": 1}


def test_an_ordering_holds_only_between_separate_intervals():
    rows = [row("left-left", 0.99, 0.98, 1.0), row("right-right", 0.90, 0.88, 0.92), row("left-right", 0.95, 0.94, 0.96),
            row("right-left", 0.50, 0.45, 0.55)]
    ok, ev = judge_ordering(rows, ("left-left",), ("right-right", "left-right", "right-left"))
    assert ok, ev


def test_a_table_whose_ordering_fails_is_not_reproduced():
    rows = [row("left-left", 0.90, 0.88, 0.92), row("right-right", 0.99, 0.98, 1.0)]
    ok, ev = judge_ordering(rows, ("left-left",), ("right-right",))
    assert not ok and "is not above" in ev


def test_overlapping_intervals_are_a_tie_not_a_reproduction():
    rows = [row("left-left", 0.96, 0.93, 0.99), row("right-right", 0.94, 0.91, 0.97)]
    ok, ev = judge_ordering(rows, ("left-left",), ("right-right",))
    assert not ok and "overlap" in ev


def test_a_row_without_a_ratio_fails_the_claim():
    rows = [row("left-left", 0.99, 0.98, 1.0), {"hands": "right-right", "ratio": None, "ratio_ci95": None,
                                                 "reason": "no feasible grasp or key poses: COM_MARGIN"}]
    ok, ev = judge_ordering(rows, ("left-left",), ("right-right",))
    assert not ok and "COM_MARGIN" in ev


def test_all_stable_needs_every_lower_bound_at_099():
    assert judge_all_stable([row("left-left", 1.0, 0.995, 1.0), row("right-right", 1.0, 0.991, 1.0)])[0]
    assert not judge_all_stable([row("left-left", 1.0, 0.995, 1.0), row("right-right", 0.995, 0.985, 1.0)])[0]


def test_the_best_stance_needs_a_separate_band():
    crouched = [row("left-left", 0.99, 0.98, 1.0), row("right-right", 0.99, 0.98, 1.0)]
    upright = [row("left-left", 0.90, 0.88, 0.92), row("right-right", 0.80, 0.78, 0.82)]
    assert judge_best_stance({"upright": upright, "crouched": crouched})[0]
    close = [row("left-left", 0.985, 0.975, 0.995), row("right-right", 0.985, 0.975, 0.995)]
    assert not judge_best_stance({"upright": close, "crouched": crouched})[0]


def test_no_removal_reads_each_plan_s_failures_by_cause():
    clean = {"status": "solved", "failures": {"collision": 3}}
    assert judge_no_removal({"left-left": clean, "left-right": clean})[0]
    ok, ev = judge_no_removal({"left-left": clean, "left-right": {"status": "solved", "failures": {"com_margin": 2}}})
    assert not ok and "left-right plan: 2 nodes removed" in ev and "left-left plan: 0 nodes removed" in ev
    ok, ev = judge_no_removal({"left-left": clean, "left-right": {"status": "infeasible", "failure": "IK"}})
    assert not ok and "left-right plan is infeasible" in ev


def test_the_threshold_claim_needs_a_breaking_plan_and_a_constrained_plan_that_keeps_it():
    def pair(free_min, cons_min, differ, status="solved"):
        return {"unconstrained": {"min_margin_m": free_min, "threshold_m": 0.0},
                "constrained": {"min_margin_m": cons_min, "threshold_m": 0.06, "status": status},
                "unconstrained_breaks_threshold": free_min < 0.06 - 1e-4, "plans_differ": differ}

    assert judge_threshold_motion({"upright": pair(0.03, 0.061, True), "staggered": pair(0.08, 0.08, False)})[0]
    assert not judge_threshold_motion({"upright": pair(0.08, 0.08, False)})[0]  # nothing to show
    assert not judge_threshold_motion({"upright": pair(0.03, None, False, "infeasible")})[0]
