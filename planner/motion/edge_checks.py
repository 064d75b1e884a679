"""Validity checks of edges and paths: a validity callback from the state evaluator and a collision test,
and the coarse-to-fine test of many edges at once that T-RRT, the shortcutter and the survey share."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from planner.stability.evaluator import HoldSpec, StateEvaluator

#: validity(Q (N, n)) -> (valid (N,) bool, margin (N,) float)
Validity = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
#: collision_free(Q (N, n)) -> (N,) bool
CollisionFree = Callable[[np.ndarray], np.ndarray]
#: Planning checks an edge's every COARSE_STRIDE-th state first (0.1 rad apart at 0.02 rad resolution).
COARSE_STRIDE = 5


def coarse_mask(n: int) -> np.ndarray:
    """The coarse states of an edge of ``n`` states: every ``COARSE_STRIDE``-th and the last
    (most invalid edges already fail there)."""
    m = np.zeros(n, dtype=bool)
    m[COARSE_STRIDE - 1 :: COARSE_STRIDE] = True
    m[-1] = True
    return m


def split_all(valid: np.ndarray, lengths: Sequence[int]) -> list[bool]:
    """Per run of consecutive states (``lengths`` of them each): whether all are valid."""
    out, k = [], 0
    for n in lengths:
        out.append(bool(valid[k : k + n].all()))
        k += n
    return out


def all_valid(parts: list[np.ndarray], validity: Validity) -> list[bool]:
    """Whether every state of each part (full configurations) is valid, in one validity call."""
    valid = np.asarray(validity(np.vstack(parts))[0], dtype=bool)
    return split_all(valid, [len(p) for p in parts])


def all_valid_coarse_to_fine(edges: list[np.ndarray], validity: Validity) -> list[bool]:
    """Whether every state of each edge (full configurations) is valid: the coarse states (every
    ``COARSE_STRIDE``-th and the last) of all edges in one validity call, then the remaining states
    of the edges that survived it in a second."""
    masks = [coarse_mask(len(e)) for e in edges]
    ok = all_valid([e[m] for e, m in zip(edges, masks)], validity)
    todo = [k for k, good in enumerate(ok) if good and not masks[k].all()]
    if todo:
        for k, good in zip(todo, all_valid([edges[k][~masks[k]] for k in todo], validity)):
            ok[k] = good
    return ok


def make_validity(
    evaluator: StateEvaluator,
    hold: HoldSpec | None,
    active: Sequence[int] | None = None,
    collision_free: CollisionFree | None = None,
    threshold_m: float | None = None,
) -> Validity:
    """A validity callback for :func:`plan_motion`: margin >= threshold first, then collision on the stable states only.

    The margin test is cheap and vectorised; the collision checker, the costly
    one, never sees a state that is already unstable. ``threshold_m`` defaults to
    the evaluator's (0 with ``margin_cost=False`` is the unconstrained planner).
    """
    act = None if active is None else np.asarray(active, dtype=int)

    def validity(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        batch = evaluator.evaluate(Q, hold, active=act, threshold_m=threshold_m)
        valid = batch.stable.copy()
        if collision_free is not None and valid.any():
            valid[valid] = np.asarray(collision_free(Q[valid]), dtype=bool)
        return valid, batch.margin

    return validity
