"""Joint-space vias within a time budget (planner/motion/time_box_vias.py): every via in a box keeps the path within
its budget at the velocity limits, and the paths found go round an obstacle on the straight line, every state valid,
the same for the same generator; where no way round fits the budget, none is returned."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.motion.interpolation import edge_states
from planner.motion.smoothing import path_length
from planner.motion.time_box_vias import BoxViaSettings, box_via_paths, via_box

LOWER, UPPER = np.full(3, -10.0), np.full(3, 10.0)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), slack=st.floats(0.0, 1.0), share=st.floats(0.05, 0.95))
def test_every_via_in_the_box_keeps_the_path_within_its_budget(seed, slack, share):
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3)
    weights = 1.0 / rng.uniform(0.3, 2.0, 3)
    line = path_length(np.vstack([a, b]), weights)
    budget = (1 + slack) * line
    low, high = via_box(a, b, weights, share * budget, budget, LOWER, UPPER)
    assert np.all(low <= high + 1e-12)
    # the straight line's own posture at that share of its time is in the box with no slack
    if slack == 0.0:
        on_line = a + share * (b - a)
        assert np.all(low - 1e-9 <= on_line) and np.all(on_line <= high + 1e-9)
    for q in low + rng.random((20, 3)) * (high - low):
        assert path_length(np.vstack([a, q]), weights) <= share * budget + 1e-9
        assert path_length(np.vstack([q, b]), weights) <= (1 - share) * budget + 1e-9
        assert path_length(np.vstack([a, q, b]), weights) <= budget + 1e-9


def _ball(centre: np.ndarray, radius: float):
    """A validity that refuses the postures within ``radius`` of ``centre`` (Euclidean, joint space)."""

    def validity(Q: np.ndarray):
        d = np.linalg.norm(np.atleast_2d(Q) - centre, axis=1)
        return d > radius, d - radius

    return validity


def test_the_paths_go_round_an_obstacle_on_the_line_within_the_budget():
    a, b = np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.3, -0.2])
    weights = np.array([1.0, 1.0, 1.0])  # joint 0 takes longest: the others have room to swing
    validity = _ball(0.5 * (a + b), 0.25)
    assert not validity(edge_states(a, b, 0.005))[0].all(), "the straight line must be blocked"
    s = BoxViaSettings()
    found = box_via_paths(a, b, validity, np.random.default_rng(1), weights, LOWER, UPPER, 0.005, s)
    assert 1 <= len(found) <= s.keep
    line = path_length(np.vstack([a, b]), weights)
    for P in found:
        assert np.array_equal(P[0], a) and np.array_equal(P[-1], b) and len(P) in (3, 4)
        dense = np.vstack([edge_states(p, q, 0.005) for p, q in zip(P[:-1], P[1:])])
        assert validity(dense)[0].all()
        assert path_length(P, weights) <= (1 + max(s.slacks)) * line + 1e-9
    # joint 0 leads: the way round costs no time at the velocity limits
    assert path_length(found[0], weights) == pytest.approx(line, rel=1e-9)


def test_the_paths_are_the_generators():
    a, b = np.zeros(3), np.array([2.0, 0.3, -0.2])
    validity = _ball(0.5 * (a + b), 0.25)
    first, second = (box_via_paths(a, b, validity, np.random.default_rng(7), np.ones(3), LOWER, UPPER, 0.005)
                     for _ in range(2))
    assert len(first) == len(second) and all(np.array_equal(p, q) for p, q in zip(first, second))


def test_no_path_where_no_way_round_fits_the_budget():
    a, b = np.zeros(3), np.array([2.0, 0.0, 0.0])
    weights = np.ones(3)
    # a wall across the whole box of the largest budget: joint 0 between 0.9 and 1.1 refused
    def validity(Q: np.ndarray):
        gap = np.abs(np.atleast_2d(Q)[:, 0] - 1.0) - 0.1
        return gap > 0, gap

    assert box_via_paths(a, b, validity, np.random.default_rng(3), weights, LOWER, UPPER, 0.005) == []
    # and none where the line does not move, or where no draws are asked for
    assert box_via_paths(a, a, validity, np.random.default_rng(3), weights, LOWER, UPPER, 0.005) == []
    assert box_via_paths(a, b, _ball(np.full(3, 5.0), 0.1), np.random.default_rng(3), weights, LOWER, UPPER, 0.005,
                         BoxViaSettings(draws=0)) == []


def test_pairs_out_of_order_are_refused():
    with pytest.raises(ValueError, match="in order"):
        BoxViaSettings(pairs=((0.6, 0.2),))
