"""Compiled damped least-squares descent of the batch IK, one target after the other.

Why compiled: each target's descent is a short loop (15-60 iterations) of tiny linear algebra (an
arm chain's forward pass, a 6 x k Jacobian, a 6 x 6 solve). Advanced together in numpy the batch
paid ~40 array operations per iteration whatever the number of targets still running, and the
stragglers kept it iterating. Here every target runs its
own loop to its own end. The iteration is that of :mod:`planner.motion.ik_batch` and :class:`planner.motion.ik.IkSolver`:
world-aligned errors and geometric Jacobian, the pull to the rest posture, joints pinned at a limit
that the step pushes further frozen and the step re-solved, the step capped, the stall rule.
"""

from __future__ import annotations

import numpy as np

from planner.compiled.jit import njit


@njit(cache=True, nogil=True)
def descend(targets, Q, active, lo, hi, rest_a, parent, R0, p0, axis_index, col,
            step_slots, step_axes, tcp_R0, tcp_p0, pos_tol, rot_tol, max_iterations, lam2, gain, max_step,
            stall_improvement, stall_iterations, limit_eps, limit_passes, R, p, ok, its, pos_err, rot_err):  # pragma: no cover - compiled
    """Run every target's descent; ``Q`` (N, nq) holds the starts and receives the results, ``ok``,
    ``its``, ``pos_err`` and ``rot_err`` (N,) the outcome, iterations and last errors.

    ``R`` (S, 3, 3, 1) and ``p`` (S, 3, 1) hold the chain's slot 0 (the frame the moving joints hang
    from) and are scratch for the rest."""
    k = active.shape[0]
    J = np.empty((6, k))
    Jf = np.empty((6, k))
    e = np.empty(6)
    pull = np.empty(k)
    dq = np.empty(k)
    free = np.empty(k, dtype=np.bool_)
    at_lo = np.empty(k, dtype=np.bool_)
    at_hi = np.empty(k, dtype=np.bool_)
    A = np.empty((6, 6))
    x = np.empty(6)
    Rt = np.empty((3, 3))
    tcp = np.empty(3)
    last = parent.shape[0] - 1
    for n in range(Q.shape[0]):
        q = Q[n]
        best = np.inf
        since = 0
        ok[n] = False
        for it in range(1, max_iterations + 2):
            _chain(q, parent, R0, p0, axis_index, col, R, p)
            # the TCP: the last slot's frame times the TCP placement
            for i in range(3):
                v = p[last, i, 0]
                for m in range(3):
                    v += R[last, i, m, 0] * tcp_p0[m]
                e[i] = targets[n, i, 3] - v
                tcp[i] = v
                for j in range(3):
                    v = 0.0
                    for m in range(3):
                        v += R[last, i, m, 0] * tcp_R0[m, j]
                    Rt[i, j] = v
            _rotation_error(targets[n], Rt, e)
            perr = np.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
            rerr = np.sqrt(e[3] * e[3] + e[4] * e[4] + e[5] * e[5])
            its[n] = it
            pos_err[n] = perr
            rot_err[n] = rerr
            if perr <= pos_tol and rerr <= rot_tol:
                ok[n] = True
                break
            score = perr + 0.1 * rerr
            if score < best * (1.0 - stall_improvement):
                best = score
                since = 0
            else:
                since += 1
            if it > max_iterations or since >= stall_iterations:
                break
            # geometric Jacobian: world axis w of each joint, and w x (TCP - joint)
            for c in range(k):
                s = step_slots[c]
                a = step_axes[c]
                wx, wy, wz = R[s, 0, a, 0], R[s, 1, a, 0], R[s, 2, a, 0]
                dx, dy, dz = tcp[0] - p[s, 0, 0], tcp[1] - p[s, 1, 0], tcp[2] - p[s, 2, 0]
                J[0, c] = wy * dz - wz * dy
                J[1, c] = wz * dx - wx * dz
                J[2, c] = wx * dy - wy * dx
                J[3, c] = wx
                J[4, c] = wy
                J[5, c] = wz
            any_limit = False
            for c in range(k):
                qa = q[active[c]]
                free[c] = True
                at_lo[c] = qa <= lo[c] + limit_eps
                at_hi[c] = qa >= hi[c] - limit_eps
                any_limit = any_limit or at_lo[c] or at_hi[c]
            _dls_step(J, e, q, active, rest_a, lam2, gain, free, Jf, pull, A, x, dq)
            if any_limit:
                for _ in range(limit_passes):
                    blocked = False
                    for c in range(k):
                        if free[c] and ((at_lo[c] and dq[c] < 0) or (at_hi[c] and dq[c] > 0)):
                            free[c] = False
                            blocked = True
                    if not blocked:
                        break
                    _dls_step(J, e, q, active, rest_a, lam2, gain, free, Jf, pull, A, x, dq)
            big = 0.0
            for c in range(k):
                big = max(big, abs(dq[c]))
            scale = max_step / big if big > max_step else 1.0
            for c in range(k):
                q[active[c]] = min(max(q[active[c]] + dq[c] * scale, lo[c]), hi[c])


@njit(cache=True, nogil=True)
def _chain(q, parent, R0, p0, axis_index, col, R, p):  # pragma: no cover - compiled
    """The arm chain's frames at ``q``: :func:`planner.compiled.tree_kernels.walk` for one configuration of plain
    revolute joints (the only kind the batch IK moves), slot 0 given."""
    for k in range(1, parent.shape[0]):
        a = parent[k]
        for i in range(3):
            v = p[a, i, 0]
            for m in range(3):
                v += R[a, i, m, 0] * p0[k, m]
            p[k, i, 0] = v
            for j in range(3):
                v = 0.0
                for m in range(3):
                    v += R[a, i, m, 0] * R0[k, m, j]
                R[k, i, j, 0] = v
        cs = np.cos(q[col[k]])
        sn = np.sin(q[col[k]])
        ii = (axis_index[k] + 1) % 3
        jj = (axis_index[k] + 2) % 3
        for i in range(3):
            ci = R[k, i, ii, 0]
            cj = R[k, i, jj, 0]
            R[k, i, ii, 0] = cs * ci + sn * cj
            R[k, i, jj, 0] = cs * cj - sn * ci


@njit(cache=True, nogil=True)
def _rotation_error(T, Rt, e):  # pragma: no cover - compiled
    """e[3:6] = the rotation vector of T[:3, :3] @ Rt^T (the target's rotation relative to the TCP's)."""
    M = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            M[i, j] = T[i, 0] * Rt[j, 0] + T[i, 1] * Rt[j, 1] + T[i, 2] * Rt[j, 2]
    vx, vy, vz = M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]
    c = min(max((M[0, 0] + M[1, 1] + M[2, 2] - 1.0) * 0.5, -1.0), 1.0)
    theta = np.arccos(c)
    s = np.sin(theta)
    if s >= 1e-6:
        f = theta / (2.0 * s)
        e[3], e[4], e[5] = vx * f, vy * f, vz * f
    elif c >= 0:
        e[3], e[4], e[5] = vx * 0.5, vy * 0.5, vz * 0.5
    else:  # a half turn: the axis is the longest column of M + I
        best, col = -1.0, 0
        for j in range(3):
            norm = (M[0, j] + (j == 0)) ** 2 + (M[1, j] + (j == 1)) ** 2 + (M[2, j] + (j == 2)) ** 2
            if norm > best:
                best, col = norm, j
        ax, ay, az = M[0, col] + (col == 0), M[1, col] + (col == 1), M[2, col] + (col == 2)
        norm = np.sqrt(ax * ax + ay * ay + az * az)
        e[3], e[4], e[5] = np.pi * ax / norm, np.pi * ay / norm, np.pi * az / norm


@njit(cache=True, nogil=True)
def _dls_step(J, e, q, active, rest_a, lam2, gain, free, Jf, pull, A, x, dq):  # pragma: no cover - compiled
    """dq = Jf^T (Jf Jf^T + lam2 I)^-1 (e - Jf pull) + pull, Jf the Jacobian with the columns of
    joints not ``free`` zeroed (they do not move), pull the gain times the way to the rest posture."""
    k = J.shape[1]
    for c in range(k):
        f = 1.0 if free[c] else 0.0
        pull[c] = gain * (rest_a[c] - q[active[c]]) * f
        for r in range(6):
            Jf[r, c] = J[r, c] * f
    for r in range(6):
        v = e[r]
        for c in range(k):
            v -= Jf[r, c] * pull[c]
        x[r] = v
        for t in range(r + 1):
            v = 0.0
            for c in range(k):
                v += Jf[r, c] * Jf[t, c]
            A[r, t] = v
        A[r, r] += lam2
    # Cholesky of the symmetric positive definite A (lower triangle), then the two triangular solves
    for r in range(6):
        for t in range(r + 1):
            v = A[r, t]
            for m in range(t):
                v -= A[r, m] * A[t, m]
            A[r, t] = np.sqrt(v) if r == t else v / A[t, t]
    for r in range(6):
        v = x[r]
        for m in range(r):
            v -= A[r, m] * x[m]
        x[r] = v / A[r, r]
    for r in range(5, -1, -1):
        v = x[r]
        for m in range(r + 1, 6):
            v -= A[m, r] * x[m]
        x[r] = v / A[r, r]
    for c in range(k):
        v = pull[c]
        for r in range(6):
            v += Jf[r, c] * x[r]
        dq[c] = v
