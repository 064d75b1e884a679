"""Both arms at once where a handover lets them: two consecutive motions of different arms made one.

Around a handover the search lays out, one after the other, motions of two arms that move different joints: the
giver carries the object to the handover pose, then the taker moves to its pre-grasp there; after the exchange the
giver goes home, then the taker carries the object away. Each waits for the other though neither needs to.
:func:`merged_pieces` makes each such pair one motion in which both arms move at once, each along its own path at
its own pace (:func:`both_at_once`), the second starting together with the first or once the first has done a share
of its way (``LEADS``: the taker's hand must not reach its pre-grasp before the object does, and the giver's hand
must be clear of the object before the taker carries it away). These are only paths: the plan's timing
(:mod:`planner.regrasp.timing.plan_timer`) times them and checks every sample, as it does the motions one after the
other, which it keeps wherever no merged path passes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from planner.regrasp.plan_assembly import MotionPiece

#: The piece kinds that may run at once with the other arm's (planned motions between key poses).
MERGEABLE = ("transit", "transfer")
#: When the second motion starts, as shares of the first one's time done: together first, then later.
LEADS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


def may_merge(a: MotionPiece, b: MotionPiece) -> bool:
    """Whether a and b (consecutive) are motions of different arms between key poses, the object held alike (by a
    hand: a resting object is where the plan tracks it, which the arms' order decides), moving no joint in common."""
    if a.kind not in MERGEABLE or b.kind not in MERGEABLE or {a.hand, b.hand} != {"left", "right"}:
        return False
    if a.holding != b.holding or a.holding == "none":
        return False
    return not np.any(_moved(a.joint_path()) & _moved(b.joint_path()))


def merged_pieces(pieces: list[MotionPiece], weights: np.ndarray, lead: float) -> list[MotionPiece] | None:
    """``pieces`` (consecutive, their paths joined end to start) with each pair that :func:`may_merge` made one
    piece of both hands along :func:`both_at_once` with ``lead`` (a transfer where either moves the object); None
    where there is no such pair."""
    out: list[MotionPiece] = []
    merged = False
    i = 0
    while i < len(pieces):
        if i + 1 < len(pieces) and may_merge(pieces[i], pieces[i + 1]):
            a, b = pieces[i], pieces[i + 1]
            W = both_at_once(a.joint_path(), b.joint_path(), weights, lead)
            kind = "transfer" if "transfer" in (a.kind, b.kind) else "transit"
            out.append(replace(a, kind=kind, hand="both", waypoints=W, path=W))
            merged = True
            i += 2
            continue
        out.append(pieces[i])
        i += 1
    return out if merged else None


def both_at_once(A: np.ndarray, B: np.ndarray, weights: np.ndarray, lead: float = 0.0) -> np.ndarray:
    """The joint path doing A (K, n) and B (M, n) at once, where B starts where A ends and they move disjoint
    joints, B starting once A has done share ``lead`` of its time (0: together; 1: one after the other). Each moves
    at its own pace in the time metric (per segment the max over joints of ``weights`` |dq|: with weights 1 / limit,
    the time at the velocity limits), so at time tau of the merged motion A is where it is at tau and B where it is at
    tau - lead x A's time, each held at its ends outside them; A's joints come from A and B's from B, the rest as
    both leave them. Its waypoints are both paths' waypoints and the times where one starts or ends, so it is
    piecewise linear as they are; it starts at A[0] and ends at B[-1]."""
    A, B = _moving(A, weights), _moving(B, weights)
    ta, tb = _times(A, weights), _times(B, weights)
    offset = lead * ta[-1]
    tau = np.unique(np.concatenate([ta, tb + offset]))
    out = np.column_stack([np.interp(tau, ta, A[:, j]) for j in range(A.shape[1])])
    moves_b = np.flatnonzero(_moved(B))
    for j in moves_b:
        out[:, j] = np.interp(tau - offset, tb, B[:, j])
    out[0], out[-1] = A[0], B[-1]  # exactly the ends (B leaves A's joints where A left them)
    return out


def _times(P: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Each waypoint's time from the path's start at the velocity limits (the time metric's arc length)."""
    return np.concatenate([[0.0], np.cumsum(np.abs(np.diff(P, axis=0) * weights).max(axis=1))])


def _moving(P: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """P without the waypoints that repeat the one before (their times would not rise)."""
    return P[np.r_[True, np.abs(np.diff(P, axis=0) * weights).max(axis=1) > 0.0]]


def _moved(P: np.ndarray) -> np.ndarray:
    return np.ptp(P, axis=0) > 0.0
