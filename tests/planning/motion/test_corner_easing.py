"""Corner easing: interior waypoints moved towards their neighbours while the path's TOPP-RA time falls. The path
keeps its ends, its time (recomputed here) never rises, every state of it stays valid (checked here independently,
densely), a move into an obstacle is never kept, and a path gives one result."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.motion.corner_easing import eased
from planner.motion.interpolation import densify
from planner.motion.topp import BlendedPath, gridpoints_for, parameterize, profile_times

from .over_the_wall import over_the_wall, wall

VLIM = np.array([1.0, 1.0, 2.0])
ALIM = np.array([2.0, 2.0, 4.0])


def topp_time(W: np.ndarray) -> float:
    """Rest-to-rest TOPP-RA time through W, blended (0.3 rad) at its corners, within VLIM and ALIM."""
    path = BlendedPath(W, np.full(len(W) - 2, 0.3), fill=True)
    grid = gridpoints_for(path, 0.05, 200)
    sd = parameterize(path, grid, VLIM, ALIM, [])
    return float(profile_times(grid, sd)[-1]) if sd is not None else np.inf


def free(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A validity with no obstacle: every state valid."""
    n = len(np.atleast_2d(Q))
    return np.ones(n, bool), np.ones(n)


def zigzag(rng: np.random.Generator) -> np.ndarray:
    """From x=0 to x=4 over the wall, the third joint zig-zagging."""
    return over_the_wall(rng, np.array([0.0, 0.8, 1.4, 2.0, 2.6, 3.2, 4.0]),
                         np.array([0.0, 1.0, 1.1, 1.15, 1.1, 1.0, 0.0]), 1, 0.6)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_easing_keeps_the_ends_never_slows_the_path_and_stays_valid(seed):
    P = zigzag(np.random.default_rng(seed))
    assert wall(densify(P, 0.01))[0].all()
    res = eased(P, wall, topp_time, 0.01, sweeps=4)
    Q = res.path
    assert np.array_equal(Q[0], P[0]) and np.array_equal(Q[-1], P[-1]) and Q.shape == P.shape
    assert res.time_before_s == topp_time(P)
    assert res.time_after_s == topp_time(Q) <= res.time_before_s
    # checked every 0.01 rad per joint: every state is within 0.005 of a checked one, so outside the wall shrunk by that
    assert wall(densify(Q, 0.001), shrink=0.005 + 1e-9)[0].all()
    assert np.array_equal(eased(P, wall, topp_time, 0.01, sweeps=4).path, Q)


def test_a_zigzag_in_free_space_gets_quicker_and_straighter():
    P = np.array([[0.0, 0.0, 0.0], [0.5, 0.3, 0.0], [1.0, -0.3, 0.0], [1.5, 0.3, 0.0], [2.0, 0.0, 0.0]])
    res = eased(P, free, topp_time, 0.01, sweeps=6)
    assert res.moves > 0 and res.time_after_s < res.time_before_s - 0.1
    assert np.abs(res.path[:, 1]).max() < np.abs(P[:, 1]).max()


def test_a_move_into_an_obstacle_is_never_kept():
    """A sharp dip under an obstacle: easing its corner would cut into it. With the obstacle, the path stays as it
    was; without it, the same moves are quicker and are kept, through where the obstacle was."""
    P = np.array([[0.0, 0.0, 0.0], [1.0, -1.0, 0.0], [2.0, 0.0, 0.0]])

    def block(Q):  # |q0 - 1| < 0.1 and q1 > -0.8 is invalid: the dip goes under it
        Q = np.atleast_2d(Q)
        return ~((np.abs(Q[:, 0] - 1.0) < 0.1) & (Q[:, 1] > -0.8)), np.ones(len(Q))

    assert block(densify(P, 0.01))[0].all()
    through = eased(P, free, topp_time, 0.01, sweeps=3)
    assert through.moves > 0 and through.time_after_s < through.time_before_s
    assert not block(densify(through.path, 0.01))[0].all()
    res = eased(P, block, topp_time, 0.01, sweeps=3)
    assert res.moves == 0 and np.array_equal(res.path, P) and res.time_after_s == res.time_before_s
    assert res.evaluations > 0  # the quicker moves were timed, then refused by the checks


def test_each_pass_that_kept_a_move_is_kept_in_order_as_fewer_passes_would_end():
    """``passes`` holds the path after each pass that kept a move, each quicker than the one before, the last the
    eased path; the k-th is what k passes alone give, so a caller can fall back to it."""
    P = np.column_stack([np.linspace(0.0, 3.0, 9), [0.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, 0.0], np.zeros(9)])
    res = eased(P, free, topp_time, 0.01, sweeps=6)
    assert len(res.passes) >= 2 and np.array_equal(res.passes[-1], res.path)
    times = [res.time_before_s] + [topp_time(Q) for Q in res.passes]
    assert all(later < earlier for earlier, later in zip(times, times[1:]))
    for k, Q in enumerate(res.passes[:-1], start=1):
        assert np.array_equal(eased(P, free, topp_time, 0.01, sweeps=k).path, Q)
    assert eased(P, free, topp_time, 0.01, sweeps=0).passes == ()
