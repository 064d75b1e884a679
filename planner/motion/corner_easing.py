"""Corner easing: a path's interior waypoints moved towards their neighbours while the path's time falls.

A shortened path keeps the corners its obstacles force, and the short segments between sharp turns leave
its blends little room, so the robot slows down at each of them. Moving an interior waypoint part of the
way towards the midpoint of its two neighbours (the elastic band's step) opens the turn there and the
turns beside it close a little; whether the path gets quicker is the caller's time of it (TOPP-RA's, which
knows the corners, the limits and the balance), and a move is kept only when that time falls and the two
straight segments it changes pass the caller's validity at ``resolution``. The path's ends never move.
Deterministic: a path and its callbacks give one result, whichever process computes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from planner.motion.edge_checks import Validity, all_valid_coarse_to_fine
from planner.motion.interpolation import edge_states

#: Shares of the way to the neighbours' midpoint a waypoint is moved, the largest tried first.
EASING_STEPS = (0.5, 0.25, 0.125)
#: A move is kept when it saves at least this much time (s): less is within the coarse timing's rounding.
MIN_GAIN_S = 1e-3


@dataclass
class EasedPath:
    """The eased path, its time before and after, the moves kept and the times asked for; ``passes``, the path after
    each pass that kept a move (the last is ``path``), so that a caller whose own checks refuse the last can fall
    back to an earlier one."""

    path: np.ndarray
    time_before_s: float
    time_after_s: float
    moves: int
    evaluations: int
    passes: tuple[np.ndarray, ...] = ()


def eased(path: np.ndarray, validity: Validity, time_of: Callable[[np.ndarray], float], resolution: float,
          sweeps: int) -> EasedPath:
    """``path`` (K, n) with its interior waypoints eased, in at most ``sweeps`` passes over them (a pass that keeps
    no move ends it). At each waypoint the steps of :data:`EASING_STEPS` are tried largest first; the first that
    ``time_of`` finds quicker by :data:`MIN_GAIN_S` and whose two changed segments pass ``validity`` (their states at
    most ``resolution`` rad apart per joint) is kept."""
    P = np.asarray(path, dtype=float).copy()
    best = before = float(time_of(P))
    moves = evaluations = 0
    passes: list[np.ndarray] = []
    for _ in range(sweeps if len(P) > 2 else 0):
        moved = False
        for i in range(1, len(P) - 1):
            toward = 0.5 * (P[i - 1] + P[i + 1]) - P[i]
            for step in EASING_STEPS:
                U = P.copy()
                U[i] = P[i] + step * toward
                evaluations += 1
                took = float(time_of(U))
                if not took < best - MIN_GAIN_S:
                    continue
                changed = np.vstack([edge_states(U[i - 1], U[i], resolution), edge_states(U[i], U[i + 1], resolution)])
                if all_valid_coarse_to_fine([changed], validity)[0]:
                    P, best, moved = U, took, True
                    moves += 1
                    break
        if not moved:
            break
        passes.append(P)
    return EasedPath(path=P, time_before_s=before, time_after_s=best, moves=moves, evaluations=evaluations,
                     passes=tuple(passes))
