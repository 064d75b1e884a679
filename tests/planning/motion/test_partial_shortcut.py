"""Partial shortcuts: one joint made linear between two points of the path while the others keep their course. The
path keeps its ends, never takes longer at the velocity limits, every state of it stays valid (checked here
independently, densely), and a seed gives one result."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.motion.interpolation import densify
from planner.motion.smoothing import partial_shortcut, path_length

from .over_the_wall import over_the_wall, wall


def _path(rng: np.random.Generator) -> np.ndarray:
    """From x=0 to x=4 over the wall, with random detours of the other joints."""
    return over_the_wall(rng, np.array([0.0, 1.0, 1.5, 2.5, 3.0, 4.0]), np.array([0.0, 1.2, 1.3, 1.3, 1.2, 0.0]),
                         2, 1.0)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_partial_shortcuts_keep_the_ends_shorten_and_stay_valid(seed):
    P = _path(np.random.default_rng(seed))
    assert wall(densify(P, 0.01))[0].all()
    w = np.array([1.0, 1.0, 2.0, 0.5])
    res = partial_shortcut(P, wall, np.random.default_rng(seed), 120, 0.01, w)
    Q = res.path
    assert np.array_equal(Q[0], P[0]) and np.array_equal(Q[-1], P[-1])
    assert path_length(Q, w) <= path_length(P, w) + 1e-12
    # checked every 0.01 rad per joint: every state of the path is within 0.005 of a checked one, so outside the
    # wall shrunk by that (a graze of the corner between two checked states is what dense checks must catch later)
    assert wall(densify(Q, 0.001), shrink=0.005 + 1e-9)[0].all()
    # the random detours of joints 2 and 3 are what a whole-path shortcut over the wall could not remove
    assert res.length_after < res.length_before
    again = partial_shortcut(P, wall, np.random.default_rng(seed), 120, 0.01, w)
    assert np.array_equal(again.path, Q)
