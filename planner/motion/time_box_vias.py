"""Paths through joint-space via postures that cost no more time at the velocity limits than the straight line, or a
set share more: the way round an obstacle that keeps the motion's slowest joint in charge.

The time a straight segment takes at the velocity limits is that of its slowest joint,
``max_j |dq_j| / v_j``. A path through a via ``q`` at share ``f`` of a budget ``T`` takes at most ``T`` wherever
every joint can reach ``q`` from the start in ``f T`` and the end from ``q`` in ``(1 - f) T``:

    max(a_j - f T v_j, b_j - (1 - f) T v_j)  <=  q_j  <=  min(a_j + f T v_j, b_j + (1 - f) T v_j)

a box round the straight line, thin along the joint that takes longest and wide along the others. With ``T`` the
straight line's own time, every path through a via in the box is as quick at the velocity limits as the line: the
slowest joint goes straight to its end while the others swing out of an obstacle's way and back. T-RRT's samples are
uniform over the joint limits and seldom fall in this thin set, so its ways round an obstacle can take far longer than
the line, and shortcuts do not take a path out of the way it went. :func:`box_via_paths` draws vias (one, or two in
turn) in the boxes of budgets ``(1 + slack) T`` from a generator, checks the via postures, then their paths (every
``resolution`` rad per joint, in levels from coarse to fine, a chunk at a time) and returns the first few valid ones,
the smallest slack first.

Only the joints that move between the ends move; the rest stay as they are at the start. Deterministic for a
generator.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from planner.motion.edge_checks import Validity, all_valid_coarse_to_fine
from planner.motion.interpolation import edge_states
from planner.motion.smoothing import path_length

Share = Annotated[float, Field(gt=0, lt=1)]
#: The levels of the paths' checks (every 25th state, then every 5th, then the rest): most drawn paths fail, and
#: the first level finds most failures for a fifth of the states.
PROBE_STRIDES = (25, 5)


class BoxViaSettings(BaseModel):
    """How many vias are drawn, where along the way, with how much more time than the straight line."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    draws: int = Field(120, ge=0, description="vias drawn per place along the way (and per pair of places) and per "
                       "slack (0: none)")
    slacks: tuple[Annotated[float, Field(ge=0, le=2)], ...] = Field(
        (0.0, 0.1, 0.2, 0.3), min_length=1, description="the budgets tried in turn: the straight line's time at the "
        "velocity limits times 1 + slack")
    fractions: tuple[Share, ...] = Field((0.25, 0.5, 0.75), description="the one via's place: share of the budget "
                                         "spent before it")
    pairs: tuple[tuple[Share, Share], ...] = Field(
        ((0.2, 0.6), (0.3, 0.7), (0.4, 0.8), (0.15, 0.85)), description="two vias' places, the second drawn in the "
        "box the first leaves")
    checked: int = Field(80, ge=0, description="paths through valid vias checked per slack at most")
    chunk: int = Field(20, ge=1, description="paths checked at once (the search stops at the chunk that makes keep)")
    keep: int = Field(3, ge=1, description="valid paths returned at most")
    min_ratio: float = Field(1.05, ge=1.0, description="drawn only where the motion's quickest path so far takes "
                             "more than this times the straight line's time at the velocity limits")

    @field_validator("pairs")
    @classmethod
    def _in_order(cls, pairs: tuple[tuple[float, float], ...]) -> tuple[tuple[float, float], ...]:
        for first, second in pairs:
            if not first < second:
                raise ValueError(f"a pair of via places must be in order along the way, got ({first}, {second})")
        return pairs


def via_box(a: np.ndarray, b: np.ndarray, weights: np.ndarray, before: float, budget: float, lower: np.ndarray,
            upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box of vias ``q`` that ``a -> q`` takes at most ``before`` and ``q -> b`` at most ``budget - before`` at
    the velocity limits, within the joint limits: (low, high), per row where ``a`` holds one start per row. Empty
    along a joint where low > high (the budget is less than the straight line's time)."""
    reach = 1.0 / weights
    low = np.maximum(a - before * reach, b - (budget - before) * reach)
    high = np.minimum(a + before * reach, b + (budget - before) * reach)
    return np.maximum(low, lower), np.minimum(high, upper)


def box_via_paths(a: np.ndarray, b: np.ndarray, validity: Validity, rng: np.random.Generator, weights: np.ndarray,
                  lower: np.ndarray, upper: np.ndarray, resolution: float,
                  settings: BoxViaSettings | None = None) -> list[np.ndarray]:
    """Up to ``keep`` valid paths from ``a`` to ``b`` through one or two vias drawn in the boxes of the straight
    line's time times ``1 + slack`` (see the module's docstring), the smallest slack first; each path (3 or 4, n)
    with its ends exactly ``a`` and ``b``, every state ``resolution`` apart valid. None (an empty list) when the line
    does not move or no draws are asked for."""
    s = settings or BoxViaSettings()
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    moving = np.flatnonzero(b != a)
    if not s.draws or not moving.size:
        return []
    w, lo, hi = weights[moving], lower[moving], upper[moving]
    line = path_length(np.vstack([a, b]), weights)
    found: list[np.ndarray] = []
    for slack in s.slacks:
        budget = (1.0 + slack) * line
        singles = _drawn(a, moving, [_one(a, b, moving, w, lo, hi, budget, f, s.draws, rng) for f in s.fractions])
        candidates = [np.vstack([a, v, b]) for v in _valid(singles, validity)]
        for first, second in s.pairs:
            V1 = _one(a, b, moving, w, lo, hi, budget, first, s.draws, rng)
            # each second via in the box of what its first leaves of the budget
            low, high = via_box(V1, b[moving], w, (second - first) * budget, (1.0 - first) * budget, lo, hi)
            V2 = low + rng.random(V1.shape) * np.maximum(high - low, 0.0)
            Q1, Q2 = _drawn(a, moving, [V1]), _drawn(a, moving, [V2])
            both = np.asarray(validity(Q1)[0], dtype=bool) & np.asarray(validity(Q2)[0], dtype=bool)
            candidates += [np.vstack([a, q1, q2, b]) for q1, q2 in zip(Q1[both], Q2[both])]
        order = rng.permutation(len(candidates))[:s.checked]
        for start in range(0, len(order), s.chunk):
            paths = [candidates[i] for i in order[start:start + s.chunk]]
            edges = [np.vstack([edge_states(p, q, resolution) for p, q in zip(P[:-1], P[1:])]) for P in paths]
            found += [P for P, ok in zip(paths, all_valid_coarse_to_fine(edges, validity, PROBE_STRIDES)) if ok]
            if len(found) >= s.keep:
                return found[:s.keep]
    return found


def _one(a: np.ndarray, b: np.ndarray, moving: np.ndarray, w: np.ndarray, lo: np.ndarray, hi: np.ndarray,
         budget: float, share: float, draws: int, rng: np.random.Generator) -> np.ndarray:
    """``draws`` vias of the moving joints, uniform in the box of one via at ``share`` of ``budget``."""
    low, high = via_box(a[moving], b[moving], w, share * budget, budget, lo, hi)
    return low + rng.random((draws, len(moving))) * np.maximum(high - low, 0.0)


def _drawn(a: np.ndarray, moving: np.ndarray, parts: list[np.ndarray]) -> np.ndarray:
    """Full postures: ``a`` with its moving joints set from each row of ``parts``."""
    V = np.vstack(parts)
    Q = np.repeat(a[None], len(V), axis=0)
    Q[:, moving] = V
    return Q


def _valid(Q: np.ndarray, validity: Validity) -> np.ndarray:
    """The postures of Q that pass ``validity``."""
    return Q[np.asarray(validity(Q)[0], dtype=bool)] if len(Q) else Q
