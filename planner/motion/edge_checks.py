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


def coarse_mask(n: int, stride: int = COARSE_STRIDE) -> np.ndarray:
    """The coarse states of an edge of ``n`` states: every ``stride``-th and the last
    (most invalid edges already fail there)."""
    m = np.zeros(n, dtype=bool)
    m[stride - 1 :: stride] = True
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


def all_valid_coarse_to_fine(edges: list[np.ndarray], validity: Validity,
                             strides: Sequence[int] = (COARSE_STRIDE,)) -> list[bool]:
    """Whether every state of each edge (full configurations) is valid: the coarse states (every
    ``strides[0]``-th and the last) of all edges in one validity call, then the states of each finer stride not
    checked yet of the edges that survived, at last the remaining states: one validity call per level. Many
    candidate edges that mostly fail (random ones) are cheaper with a coarser first level; every state is checked
    once, and the answer is the same whatever the strides."""
    ok = [True] * len(edges)
    checked = [np.zeros(len(e), dtype=bool) for e in edges]
    for stride in (*strides, 1):
        masks = {k: coarse_mask(len(edges[k]), stride) & ~checked[k] for k in range(len(edges)) if ok[k]}
        todo = [k for k, m in masks.items() if m.any()]
        if not todo:
            break
        for k, good in zip(todo, all_valid([edges[k][masks[k]] for k in todo], validity)):
            ok[k] = good
            checked[k] |= masks[k]
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
