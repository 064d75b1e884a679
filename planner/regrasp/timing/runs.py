"""A plan's runs: the pieces traversed without stopping, rest between them where the task needs it (the holding
changes, a jaw moves), their waypoints, and what is held and grasped along them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from planner.regrasp.plan_assembly import MotionPiece, object_states
from planner.stability.evaluator import HoldSpec

#: Waypoints closer than this (rad, per joint) are one.
SAME_WAYPOINT_RAD = 1e-9


@dataclass
class Run:
    """Pieces traversed without stopping: their joint path and what is held along it."""

    pieces: list[MotionPiece]
    holding: Literal["none", "left", "right", "both"]
    hold: HoldSpec | None
    free_object: np.ndarray | None
    #: the search's own path of the run (its pieces' waypoints), whose straight segments the search validated
    validated: np.ndarray | None = None


def _jaw_moves(piece: MotionPiece, jaw_cols: np.ndarray) -> bool:
    P = piece.joint_path()
    return bool(jaw_cols.size and np.abs(P[-1, jaw_cols] - P[0, jaw_cols]).max() > 0.0)


def runs_of(pieces: list[MotionPiece], task) -> list[Run]:
    """Split the plan into runs: rest where the holding changes and around every jaw move."""
    jaw_cols = np.concatenate([np.asarray(v, dtype=int) for v in task.jaw.values()]) if task.jaw else np.zeros(0, int)
    runs: list[Run] = []
    prev_jaw = False
    for piece, holding, hold, current in object_states(pieces, task.evaluator, task.placements[task.start_id]):
        jaw = _jaw_moves(piece, jaw_cols)
        if runs and runs[-1].holding == holding and not jaw and not prev_jaw:
            runs[-1].pieces.append(piece)
        else:
            runs.append(Run([piece], holding, hold, None if hold is not None else current.copy()))
        prev_jaw = jaw
    return runs


def grasping_of(piece: MotionPiece, hold: HoldSpec | None) -> str | None:
    """The hand whose fingers touch the object by design along a piece, as the search checked it: the moving hand
    of an approach or a retreat; at a handover's jaw moves, the hand other than the one the object follows."""
    if piece.kind in ("approach", "retreat") and piece.hand in ("left", "right"):
        return piece.hand
    if piece.kind == "handover" and hold is not None:
        return "right" if hold.tcp_side == "left" else "left"
    return None


def off_path(Q: np.ndarray, W: np.ndarray | None, tol: float = 1e-7) -> np.ndarray:
    """Whether each state of Q (N, n) lies off the polyline W (K, n) (all of them when W is None)."""
    if W is None or len(W) < 2:
        return np.ones(len(Q), dtype=bool)
    a, d = W[:-1], np.diff(W, axis=0)  # (K-1, n)
    dd = np.maximum((d * d).sum(axis=1), 1e-300)
    off = np.ones(len(Q), dtype=bool)
    for start in range(0, len(Q), 256):
        q = Q[start:start + 256, None, :]
        t = np.clip(((q - a) * d).sum(axis=2) / dd, 0.0, 1.0)
        dist = np.abs(q - (a + t[..., None] * d)).max(axis=2).min(axis=1)
        off[start:start + 256] = dist > tol
    return off


def waypoints_of(run: Run) -> tuple[np.ndarray, list[int]]:
    """The run's waypoints (duplicates merged) and the index of the waypoint each piece starts at."""
    W: list[np.ndarray] = []
    starts = []
    for piece in run.pieces:
        P = piece.joint_path()
        starts.append(max(len(W) - 1, 0))
        for q in P:
            if not W or np.abs(q - W[-1]).max() > SAME_WAYPOINT_RAD:
                W.append(q)
    return np.array(W), starts


def is_planned(piece: MotionPiece) -> bool:
    """Whether a piece is a planned motion (more than one straight segment), which the timing makes quicker."""
    return piece.path is not None and len(piece.path) > 2
