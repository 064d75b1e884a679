"""Compiled inner loops of the collision screen: body boxes in the world, the per-state box screen,
and the oriented-box separating-axis test (SAT).

Why compiled: the screen tests every surviving body pair in every state of a batch; in numpy that
was ~20 array operations over (pairs x states) masks and gathers per batch, most of a check's time
on T-RRT batches of ~40 states. Here it is one pass that keeps only the
(pair, state) candidates the exact tests need. The SAT agrees with fcl and the screens drop
nothing it keeps (property tests); the grasp and handover filters use the SAT on its own.
"""

from __future__ import annotations

import numpy as np

from planner.compiled.jit import njit

#: Guard against the cross-product axes of nearly parallel box edges in the SAT.
SAT_EPS = 1e-9


def obb_penetration(Ra: np.ndarray, ca: np.ndarray, ea: np.ndarray, Rb: np.ndarray, cb: np.ndarray, eb: np.ndarray) -> np.ndarray:
    """Penetration depth of oriented boxes (K pairs); negative = separated by at least that much.

    Rotations (K, 3, 3), centres (K, 3), half sizes (K, 3). The separating-axis theorem
    with the 15 axes of two boxes is exact for boxes; the smallest overlap over the axes
    is the penetration depth (a lower bound of the separation distance when negative).
    """
    args = [np.ascontiguousarray(x, dtype=float) for x in (Ra, ca, ea, Rb, cb, eb)]
    out = np.empty(args[0].shape[0])
    _obb_depths(*args, SAT_EPS, out)
    return out


def hypotheses_hit(Ra: np.ndarray, ca: np.ndarray, ea: np.ndarray, Rb: np.ndarray, cb: np.ndarray, eb: np.ndarray,
                   box_a: np.ndarray, box_b: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """For K hypotheses of two body sets (rotations (K, A, 3, 3), box centres (K, A, 3), half sizes
    (A, 3); the same for B): whether a box pair of a hypothesis penetrates deeper than ``tol`` (K,),
    and the (k, a, b) pairs where a non-box shape's box does (the caller decides those exactly)."""
    K, A, B = Ra.shape[0], Ra.shape[1], Rb.shape[1]
    hit = np.zeros(K, dtype=np.bool_)
    cand = np.empty((K * A * B, 3), dtype=np.int64)
    n = _hypotheses_hit(*[np.ascontiguousarray(x, dtype=float) for x in (Ra, ca, ea, Rb, cb, eb)],
                        np.asarray(box_a, dtype=np.bool_), np.asarray(box_b, dtype=np.bool_), float(tol), SAT_EPS, hit, cand)
    return hit, cand[:n]


def bodies_world(R: np.ndarray, p: np.ndarray, body_joint: np.ndarray, local_R: np.ndarray, local_p: np.ndarray,
                 Rw: np.ndarray, pw: np.ndarray) -> None:
    """World rotation ``Rw`` (n, N, 3, 3) and box centre ``pw`` (n, N, 3) of n bodies, each fixed at
    ``local_R``, ``local_p`` in the frame of joint ``body_joint`` of a forward pass ``R`` (J, 3, 3, N),
    ``p`` (J, 3, N)."""
    _bodies_world(R, p, body_joint, local_R, local_p, Rw, pw)


def screen_pairs(Rw: np.ndarray, pw: np.ndarray, half: np.ndarray, ia: np.ndarray, ib: np.ndarray, slack: np.ndarray,
                 tol: np.ndarray, envelope_rounding: float) -> tuple[np.ndarray, np.ndarray]:
    """The (pair, state) candidates of body pairs ``ia``, ``ib`` over the states of ``Rw`` (B, N, 3, 3),
    ``pw`` (B, N, 3), pair-major: the oriented boxes (half sizes ``half`` (B, 3)) penetrate deeper than
    ``tol`` (P,). Screens first, per pair: the world axis-aligned boxes of the two bodies over the
    whole batch (widened by ``envelope_rounding``, never stricter than what follows), then per state,
    each closer than ``slack`` (P,)."""
    B, N = Rw.shape[0], Rw.shape[1]
    ext = np.empty((B, N, 3))
    lo = np.empty((B, 3))
    hi = np.empty((B, 3))
    _world_boxes(Rw, pw, half, ext, lo, hi)
    P = ia.size
    kp = np.empty(P * N, dtype=np.int64)
    ks = np.empty(P * N, dtype=np.int64)
    n = _screen_pairs(Rw, pw, ext, lo, hi, half, ia, ib, slack, tol, SAT_EPS, envelope_rounding, kp, ks)
    return kp[:n], ks[:n]


@njit(cache=True, nogil=True)
def _bodies_world(R, p, body_joint, local_R, local_p, Rw, pw):  # pragma: no cover - compiled
    N = R.shape[3]
    for b in range(body_joint.shape[0]):
        j = body_joint[b]
        for n in range(N):
            for i in range(3):
                v = p[j, i, n]
                for m in range(3):
                    v += R[j, i, m, n] * local_p[b, m]
                pw[b, n, i] = v
                for c in range(3):
                    v = 0.0
                    for m in range(3):
                        v += R[j, i, m, n] * local_R[b, m, c]
                    Rw[b, n, i, c] = v


@njit(cache=True, nogil=True)
def _world_boxes(Rw, pw, half, ext, lo, hi):  # pragma: no cover - compiled
    """Half sizes of the world axis-aligned box of every body in every state, and each body's box
    over all states."""
    for b in range(Rw.shape[0]):
        for c in range(3):
            lo[b, c] = np.inf
            hi[b, c] = -np.inf
        for n in range(Rw.shape[1]):
            for c in range(3):
                e = abs(Rw[b, n, c, 0]) * half[b, 0] + abs(Rw[b, n, c, 1]) * half[b, 1] + abs(Rw[b, n, c, 2]) * half[b, 2]
                ext[b, n, c] = e
                lo[b, c] = min(lo[b, c], pw[b, n, c] - e)
                hi[b, c] = max(hi[b, c], pw[b, n, c] + e)


@njit(cache=True, nogil=True)
def _obb_depths(Ra, ca, ea, Rb, cb, eb, eps, out):  # pragma: no cover - compiled
    R, A, t = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    for k in range(out.shape[0]):
        out[k] = _obb_depth(Ra[k], ca[k], ea[k], Rb[k], cb[k], eb[k], eps, R, A, t)


@njit(cache=True, nogil=True)
def _hypotheses_hit(Ra, ca, ea, Rb, cb, eb, box_a, box_b, tol, eps, hit, cand):  # pragma: no cover - compiled
    R, A, t = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    n = 0
    for k in range(Ra.shape[0]):
        for a in range(Ra.shape[1]):
            for b in range(Rb.shape[1]):
                if _obb_depth(Ra[k, a], ca[k, a], ea[a], Rb[k, b], cb[k, b], eb[b], eps, R, A, t) > tol:
                    if box_a[a] and box_b[b]:
                        hit[k] = True
                    else:
                        cand[n, 0], cand[n, 1], cand[n, 2] = k, a, b
                        n += 1
                if hit[k]:
                    break
            if hit[k]:
                break
    return n


@njit(cache=True, nogil=True)
def _obb_depth(Ra, ca, ea, Rb, cb, eb, eps, R, A, t):  # pragma: no cover - compiled
    """:func:`obb_penetration` for one pair; ``R``, ``A`` (3, 3) and ``t`` (3,) are the caller's scratch
    (one allocation per kernel call, not per pair)."""
    for i in range(3):
        v = 0.0
        for m in range(3):
            v += Ra[m, i] * (cb[m] - ca[m])
        t[i] = v
        for j in range(3):
            v = 0.0
            for m in range(3):
                v += Ra[m, i] * Rb[m, j]
            R[i, j] = v
            A[i, j] = abs(v) + eps
    best = np.inf
    for i in range(3):
        d = ea[i] + A[i, 0] * eb[0] + A[i, 1] * eb[1] + A[i, 2] * eb[2] - abs(t[i])
        best = min(best, d)
    for j in range(3):
        tb = R[0, j] * t[0] + R[1, j] * t[1] + R[2, j] * t[2]
        d = A[0, j] * ea[0] + A[1, j] * ea[1] + A[2, j] * ea[2] + eb[j] - abs(tb)
        best = min(best, d)
    for i in range(3):
        i1 = (i + 1) % 3
        i2 = (i + 2) % 3
        for j in range(3):
            j1 = (j + 1) % 3
            j2 = (j + 2) % 3
            norm = np.sqrt(max(1.0 - R[i, j] ** 2, 0.0))
            if norm > 1e-6:
                ra = ea[i1] * A[i2, j] + ea[i2] * A[i1, j]
                rb = eb[j1] * A[i, j2] + eb[j2] * A[i, j1]
                proj = abs(t[i2] * R[i1, j] - t[i1] * R[i2, j])
                best = min(best, (ra + rb - proj) / norm)
    return best


@njit(cache=True, nogil=True)
def _screen_pairs(Rw, pw, ext, lo, hi, half, ia, ib, slack, tol, sat_eps, envelope_rounding, kp, ks):  # pragma: no cover - compiled
    N = Rw.shape[1]
    R, A, t = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    count = 0
    for k in range(ia.shape[0]):
        a = ia[k]
        b = ib[k]
        if N > 1:
            wide = slack[k] + envelope_rounding
            apart = False
            for c in range(3):
                if not (lo[a, c] < hi[b, c] + wide and lo[b, c] < hi[a, c] + wide):
                    apart = True
                    break
            if apart:
                continue
        for s in range(N):
            near = True
            for c in range(3):
                if not abs(pw[a, s, c] - pw[b, s, c]) < ext[a, s, c] + ext[b, s, c] + slack[k]:
                    near = False
                    break
            if not near:
                continue
            d = _obb_depth(Rw[a, s], pw[a, s], half[a], Rw[b, s], pw[b, s], half[b], sat_eps, R, A, t)
            if d > tol[k]:
                kp[count] = k
                ks[count] = s
                count += 1
    return count
