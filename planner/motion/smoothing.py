"""Shortcut smoothing of a piecewise-linear joint path.

A T-RRT path zig-zags through the sampled space. Random shortcuts replace the
stretch between two random points of the path (anywhere on its segments, not
only at waypoints) by a straight segment when every state along it, at the
same resolution the planner used, passes the caller's validity callback
(collision + margin >= threshold). Then waypoints that a straight line can skip
are dropped. The random choices come from the caller's generator, so a seed
gives the same result; the path only ever gets shorter and stays valid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.motion.edge_checks import (
    Validity,
    all_valid,
    all_valid_coarse_to_fine,
    coarse_mask,
)
from planner.motion.interpolation import edge_states
from planner.termination import Termination

#: Straight-line skips tried per waypoint in the final pass (farthest first).
MAX_SKIP_TRIES = 8


class SmoothingSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    iterations: int = Field(60, ge=0, description="random shortcut attempts")
    batch: int = Field(4, ge=1, description="shortcut attempts checked together per round (the longest valid one is taken)")
    edge_resolution_rad: float = Field(0.02, gt=0, description="largest per-joint change between checked states")
    min_gain: float = Field(1e-3, ge=0, description="ignore shortcuts that save less path length than this (rad)")


@dataclass
class SmoothResult:
    path: np.ndarray
    length_before: float
    length_after: float
    stats: dict = field(default_factory=dict)


def path_length(path: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Length of a piecewise-linear path: Euclidean in joint space, or with per-joint ``weights`` the sum over
    segments of max_j weights_j |dq_j| (with weights 1 / velocity limit: the time the segment takes at the limits)."""
    P = np.asarray(path, dtype=float)
    return float(_segment_lengths(P, weights).sum()) if len(P) > 1 else 0.0


def _segment_lengths(P: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    D = np.diff(P, axis=0)
    return np.linalg.norm(D, axis=1) if weights is None else np.abs(D * weights).max(axis=1)


def _distance(a: np.ndarray, b: np.ndarray, weights: np.ndarray | None) -> float:
    return float(np.linalg.norm(b - a)) if weights is None else float(np.abs((b - a) * weights).max())


def _point_at(path: np.ndarray, cum: np.ndarray, s: float) -> tuple[int, np.ndarray]:
    """Segment index and point at arc length s."""
    i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(path) - 2))
    seg = cum[i + 1] - cum[i]
    f = 0.0 if seg <= 0 else (s - cum[i]) / seg
    return i, path[i] + f * (path[i + 1] - path[i])


def shortcut(
    path: np.ndarray,
    validity: Validity,
    rng: np.random.Generator,
    settings: SmoothingSettings | None = None,
    termination: Termination | None = None,
    weights: np.ndarray | None = None,
) -> SmoothResult:
    """Shorten ``path`` (K, n) with random valid shortcuts; returns the new path (endpoints unchanged).

    ``settings.iterations`` shortcuts are drawn; ``termination`` (the motion's) ends the smoothing
    early on a cancel or past the user's deadline, keeping the path shortened so far. ``weights`` (n,)
    measures the path as :func:`path_length` does (default Euclidean)."""
    s = settings or SmoothingSettings()
    P = np.asarray(path, dtype=float).copy()
    before = path_length(P, weights)
    tried = accepted = 0
    drawn = 0
    while drawn < s.iterations:
        if len(P) < 3 or (termination is not None and termination.should_stop()):
            break
        cum = np.concatenate([[0.0], np.cumsum(_segment_lengths(P, weights))])
        total = cum[-1]
        if total <= 0:
            break
        # One round: a few random shortcuts of the current path, checked together (two validity
        # calls per round instead of up to two per shortcut); the longest valid one is taken.
        cands = []
        for _ in range(min(s.batch, s.iterations - drawn)):
            drawn += 1
            s1, s2 = np.sort(rng.uniform(0.0, total, 2))
            i, a = _point_at(P, cum, s1)
            j, b = _point_at(P, cum, s2)
            if j <= i:
                continue  # both on one segment: already straight
            gain = (s2 - s1) - _distance(a, b, weights)
            if gain >= s.min_gain:
                cands.append((gain, i, j, a, b, np.vstack([a[None], edge_states(a, b, s.edge_resolution_rad)])))
        if not cands:
            continue
        tried += len(cands)
        ok = all_valid_coarse_to_fine([c[5] for c in cands], validity)
        valid = [c for c, good in zip(cands, ok) if good]
        if not valid:
            continue
        gain, i, j, a, b, _ = max(valid, key=lambda c: c[0])
        accepted += 1
        P = _dedupe(np.vstack([P[: i + 1], a[None], b[None], P[j + 1 :]]))
    P, dropped = _drop_skippable(P, validity, s.edge_resolution_rad)
    return SmoothResult(path=P, length_before=before, length_after=path_length(P, weights),
                        stats=dict(shortcuts_tried=tried, shortcuts_accepted=accepted, waypoints_dropped=dropped))


def _dedupe(P: np.ndarray) -> np.ndarray:
    keep = [0]
    for k in range(1, len(P)):
        if np.abs(P[k] - P[keep[-1]]).max() > 1e-12:
            keep.append(k)
    if keep[-1] != len(P) - 1:
        keep[-1] = len(P) - 1
    return P[keep]


def _drop_skippable(P: np.ndarray, validity: Validity, resolution: float) -> tuple[np.ndarray, int]:
    """Greedy pass: from each kept waypoint, jump to the farthest one reachable in a straight valid line
    (the candidate jumps of a waypoint are checked together)."""
    if len(P) < 3:
        return P, 0
    out = [0]
    i = 0
    while i < len(P) - 1:
        nxt = i + 1
        candidates = np.unique(np.linspace(i + 2, len(P) - 1, MAX_SKIP_TRIES).astype(int))[::-1] if i + 2 < len(P) else []
        if len(candidates):
            edges = [edge_states(P[i], P[j], resolution) for j in candidates]
            masks = [coarse_mask(len(e)) for e in edges]
            coarse_ok = all_valid([e[m] for e, m in zip(edges, masks)], validity)
            for j, e, m, good in zip(candidates, edges, masks, coarse_ok):  # farthest first
                if good and (m.all() or all_valid([e[~m]], validity)[0]):
                    nxt = int(j)
                    break
        out.append(nxt)
        i = nxt
    return P[out], len(P) - len(out)


def partial_shortcut(
    path: np.ndarray,
    validity: Validity,
    rng: np.random.Generator,
    iterations: int,
    resolution: float,
    weights: np.ndarray,
    batch: int = 4,
) -> SmoothResult:
    """Shorten ``path`` (K, n) in the time metric by partial shortcuts: between two random points of the path one
    random moving joint is made to change linearly (in the path's own parameter) while the others keep their
    course. A whole-path shortcut cannot remove a detour of one joint that the others need around an obstacle;
    this can, and the time a path takes at the velocity limits is set by the slowest joint of each segment.
    Candidates are drawn ``batch`` at a time, their new segments checked together at ``resolution`` (as the search
    checks its own), and the one that saves the most time is taken. Endpoints unchanged; seed-determined."""
    P = np.asarray(path, dtype=float).copy()
    before = path_length(P, weights)
    moving = np.flatnonzero(np.ptp(P, axis=0) > 0)
    drawn = accepted = 0
    while drawn < iterations and len(P) >= 3 and moving.size:
        cum = np.concatenate([[0.0], np.cumsum(_segment_lengths(P, weights))])
        total = cum[-1]
        if total <= 0:
            break
        cands = []
        for _ in range(min(batch, iterations - drawn)):
            drawn += 1
            s1, s2 = np.sort(rng.uniform(0.0, total, 2))
            joint = int(moving[rng.integers(moving.size)])
            i, a = _point_at(P, cum, s1)
            j, b = _point_at(P, cum, s2)
            if j <= i:
                continue
            mid = np.vstack([a[None], P[i + 1: j + 1], b[None]])
            u = np.concatenate([[s1], cum[i + 1: j + 1], [s2]])
            new = mid.copy()
            new[:, joint] = a[joint] + (u - s1) / max(s2 - s1, 1e-300) * (b[joint] - a[joint])
            gain = path_length(mid, weights) - path_length(new, weights)
            if gain >= 1e-4:
                states = np.vstack([edge_states(x, y, resolution) for x, y in zip(new[:-1], new[1:])])
                cands.append((gain, i, j, new, states))
        if not cands:
            continue
        ok = all_valid_coarse_to_fine([c[4] for c in cands], validity)
        valid = [c for c, good in zip(cands, ok) if good]
        if not valid:
            continue
        _, i, j, new, _ = max(valid, key=lambda c: c[0])
        accepted += 1
        P = _dedupe(np.vstack([P[: i + 1], new, P[j + 1:]]))
    P, dropped = _drop_skippable(P, validity, resolution)  # a straight line is never longer in a norm
    return SmoothResult(path=P, length_before=before, length_after=path_length(P, weights),
                        stats=dict(partial_shortcuts_tried=drawn, partial_shortcuts_accepted=accepted,
                                   waypoints_dropped=dropped))
