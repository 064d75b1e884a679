"""Inverse kinematics for many TCP targets at once: one damped least-squares descent per target,
all of them advanced together in numpy.

Why: the regrasp search weighs every grasp node by the CoM margin it will have, and that margin
depends on the arm's posture at the grasp, which only IK gives. Solved one by one (pinocchio,
~0.7 ms per target) that is about a second for the ~1,400 nodes of a paper scenario; advanced
together (one vectorised forward pass along the arm's chain and one batched 6x6 solve per
iteration) it is ~0.1 ms per target at a thousand targets (``benchmarks/bench_motion.py``).

The descent is the first attempt of :class:`planner.ik.IkSolver` (same settings, seed, rest
posture, step cap, joint-limit handling and stall rule), in world-aligned errors and Jacobians
instead of LOCAL ``log6`` ones: the iterates differ, so a target can land on another solution
(the outcomes agree on ~98 % of random reachable targets, see the tests). Restarts are the
caller's: it passes one start configuration per target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .ik import (
    LIMIT_EPS,
    LIMIT_PASSES,
    STALL_IMPROVEMENT,
    STALL_ITERATIONS,
    IkSettings,
    active_columns,
)
from .kinematics_batch import BatchKinematics, _affine, _rotate
from .robot_model import RobotModel
from .transforms import quat_to_matrix
from .tree_kernels import ROOT_SLOT, TreeSpec, tree_from_rows, walk

#: Targets advanced together per chunk: bounds the working arrays (~40 kB per target per joint).
CHUNK = 2048


@dataclass(frozen=True)
class BatchIkResult:
    """``q`` (N, nq): the solutions (rows where ``ok`` is False hold the last iterate); iterations per row."""

    q: np.ndarray
    ok: np.ndarray
    iterations: np.ndarray


@dataclass(frozen=True)
class _Chain:
    """The joints from the root to one hand's TCP, split where the first joint IK moves sits."""

    prefix: list  # root-most first, up to the first moving joint: the same frame for every target
    tree: TreeSpec  # slot 0: the frame before the moving joints (given); then the moving joints to the TCP's
    step_slots: np.ndarray  # the slots of the joints IK moves, in the order of the active columns
    step_axes: np.ndarray  # their rotation axes (index of the frame's column)


class BatchIk:
    """First-attempt IK of one hand for many targets, from one seed posture."""

    def __init__(self, robot: RobotModel, kinematics: BatchKinematics, settings: IkSettings):
        self.robot = robot
        self.kin = kinematics
        self.settings = settings
        self._chains: dict[tuple, _Chain] = {}

    def _chain(self, side: str, active: np.ndarray) -> _Chain:
        """The chain to ``side``'s TCP; every joint from the first active one on must be a plain revolute
        joint, and every active joint on the chain."""
        key = (side, active.tobytes())
        if key not in self._chains:
            by_jid = {s.jid: s for s in self.kin._steps}
            j = self.kin._frames[self.robot.spec.arms[side].tcp][0]
            chain = []
            while j in by_jid:
                chain.append(by_jid[j])
                j = by_jid[j].parent
            chain.reverse()
            by_col = {st.q_col: st for st in chain}
            off = [self.robot.joint_names[c] for c in active if c not in by_col]
            if off:
                raise ValueError(f"joints IK moves must lie on the chain to the TCP, not {', '.join(off)}")
            moved = set(active.tolist())
            first = next(i for i, st in enumerate(chain) if st.q_col in moved)
            moving = chain[first:]
            odd = [self.robot.joint_names[st.q_col] for st in moving if st.kind != "R" or st.mult != 1.0 or st.offset != 0.0]
            if odd:
                raise ValueError(f"batch IK supports plain revolute joints only, not {', '.join(odd)}")
            slot = {st.jid: k + 1 for k, st in enumerate(moving)}
            slot[moving[0].parent] = 0
            tree = tree_from_rows([ROOT_SLOT, *(st.slot(slot[st.parent]) for st in moving)])
            steps = [by_col[c] for c in active]
            self._chains[key] = _Chain(chain[:first], tree, np.array([slot[st.jid] for st in steps]),
                                       np.array([st.axis_index for st in steps]))
        return self._chains[key]

    def _parent_frame(self, chain: _Chain, base_pose: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World frame (R (3, 3, 1), p (3, 1)) of the joint before the moving ones, at configuration ``q``."""
        R, p = quat_to_matrix(base_pose[3:])[:, :, None].copy(), base_pose[:3, None].copy()
        for st in chain.prefix:
            R, p = st.place(R, p, st.value(q[st.q_col : st.q_col + 1]))
        return R, p

    def _forward(self, side: str, chain: _Chain, parent: tuple[np.ndarray, np.ndarray], Q: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """World frames (R (S, 3, 3, N), p (S, 3, N)) of the chain's slots, and the TCP's R (N, 3, 3),
        p (N, 3): :meth:`BatchKinematics.forward`'s walk, on the few joints that move."""
        n = Q.shape[0]
        R = np.empty((chain.tree.size, 3, 3, n))
        p = np.empty((chain.tree.size, 3, n))
        R[0], p[0] = parent
        walk(chain.tree, Q, R, p, first=1)
        _, R0, p0 = self.kin._frames[self.robot.spec.arms[side].tcp]
        R_last, p_last = R[-1], p[-1]  # the TCP hangs from the chain's last joint
        return R, p, np.moveaxis(_rotate(R_last, R0), 2, 0), _affine(p_last, R_last, p0).T

    def active_columns(self, side: str) -> np.ndarray:
        return active_columns(self.robot, self.settings, [side])

    def solve(self, side: str, targets: np.ndarray, base_pose: np.ndarray, seed_q: np.ndarray,
              rest_q: np.ndarray) -> BatchIkResult:
        """Move the waist (if the settings use it) and one arm so the TCP reaches each world pose of
        ``targets`` (N, 4, 4), each descent starting at ``seed_q`` (one configuration for all, or one per
        target (N, nq))."""
        targets = np.asarray(targets, dtype=float)
        n = targets.shape[0]
        active = self.active_columns(side)
        chain = self._chain(side, active)
        seed_q = np.asarray(seed_q, dtype=float)
        q_out = np.repeat(seed_q[None], n, axis=0) if seed_q.ndim == 1 else seed_q.copy()
        fixed = np.ones(self.robot.nq, dtype=bool)
        fixed[active] = False
        if n and np.any(q_out[:, fixed] != q_out[0, fixed]):
            raise ValueError("seeds may differ only in the joints IK moves")
        ok = np.zeros(n, dtype=bool)
        its = np.zeros(n, dtype=int)
        if n:
            parent = self._parent_frame(chain, np.asarray(base_pose, dtype=float), q_out[0])
        for lo in range(0, n, CHUNK):
            sl = slice(lo, min(n, lo + CHUNK))
            q_out[sl], ok[sl], its[sl] = self._descend(side, chain, parent, targets[sl], q_out[sl], rest_q, active)
        return BatchIkResult(q_out, ok, its)

    def _descend(self, side: str, chain: _Chain, parent: tuple[np.ndarray, np.ndarray], targets: np.ndarray,
                 Q: np.ndarray, rest_q: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = self.settings
        n, k = Q.shape[0], len(active)
        lo, hi = self.robot.lower[active], self.robot.upper[active]
        Q = Q.copy()
        Q[:, active] = np.clip(Q[:, active], lo, hi)
        rest_a = np.asarray(rest_q, dtype=float)[active]
        lam2_eye = s.damping**2 * np.eye(6)
        ok = np.zeros(n, dtype=bool)
        its = np.zeros(n, dtype=int)
        best = np.full(n, np.inf)
        since = np.zeros(n, dtype=int)
        live = np.arange(n)
        for it in range(1, s.max_iterations + 2):
            if live.size == 0:
                break
            Ql = Q[live]
            R_all, p_all, R_tcp, p_tcp = self._forward(side, chain, parent, Ql)
            e_p = targets[live, :3, 3] - p_tcp
            e_r = _log_rotation(targets[live, :3, :3] @ np.swapaxes(R_tcp, 1, 2))
            perr = np.linalg.norm(e_p, axis=1)
            rerr = np.linalg.norm(e_r, axis=1)
            its[live] = it
            done = (perr <= s.pos_tol_m) & (rerr <= s.rot_tol_rad)
            ok[live[done]] = True
            score = perr + 0.1 * rerr
            improved = score < best[live] * (1.0 - STALL_IMPROVEMENT)
            best[live] = np.where(improved, score, best[live])
            since[live] = np.where(improved, 0, since[live] + 1)
            keep = ~done & (since[live] < STALL_ITERATIONS)
            if it > s.max_iterations:
                break
            if not keep.any():
                break
            live, Ql, e_p, e_r, p_tcp = live[keep], Ql[keep], e_p[keep], e_r[keep], p_tcp[keep]
            # Geometric Jacobian: world axis w of each joint, and w x (TCP - joint) for the position.
            W = R_all[chain.step_slots, :, chain.step_axes][:, :, keep]  # (k, 3, n)
            D = p_tcp.T[None] - p_all[chain.step_slots][:, :, keep]
            J = np.empty((live.size, 6, k))
            J[:, 0] = (W[:, 1] * D[:, 2] - W[:, 2] * D[:, 1]).T
            J[:, 1] = (W[:, 2] * D[:, 0] - W[:, 0] * D[:, 2]).T
            J[:, 2] = (W[:, 0] * D[:, 1] - W[:, 1] * D[:, 0]).T
            J[:, 3:] = W.transpose(2, 1, 0)
            e = np.concatenate([e_p, e_r], axis=1)
            qa = Ql[:, active]
            dq = _dls_steps(J, e, qa, rest_a, lam2_eye, s.nullspace_gain, np.ones((live.size, k), dtype=bool))
            at_lo, at_hi = qa <= lo + LIMIT_EPS, qa >= hi - LIMIT_EPS
            if at_lo.any() or at_hi.any():
                free = np.ones((live.size, k), dtype=bool)
                for _ in range(LIMIT_PASSES):
                    blocked = free & ((at_lo & (dq < 0)) | (at_hi & (dq > 0)))
                    rows = blocked.any(axis=1)
                    if not rows.any():
                        break
                    free &= ~blocked
                    dq[rows] = _dls_steps(J[rows], e[rows], qa[rows], rest_a, lam2_eye, s.nullspace_gain, free[rows])
            big = np.abs(dq).max(axis=1)
            scale = np.where(big > s.max_step_rad, s.max_step_rad / np.maximum(big, 1e-300), 1.0)
            Q[live[:, None], active[None, :]] = np.clip(qa + dq * scale[:, None], lo, hi)
        return Q, ok, its


def _dls_steps(J: np.ndarray, e: np.ndarray, qa: np.ndarray, rest_a: np.ndarray, lam2_eye: np.ndarray, gain: float,
               free: np.ndarray) -> np.ndarray:
    """Damped least-squares steps (N, k) towards the errors plus the pull to the rest posture; joints
    not ``free`` do not move (their Jacobian columns are dropped)."""
    Jf = J * free[:, None, :]
    pull = gain * (rest_a[None] - qa) * free
    A = Jf @ np.swapaxes(Jf, 1, 2) + lam2_eye
    rhs = e - np.einsum("nij,nj->ni", Jf, pull)
    x = np.linalg.solve(A, rhs[:, :, None])[:, :, 0]
    return np.einsum("nij,ni->nj", Jf, x) + pull


def _log_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (N, 3) of rotation matrices (N, 3, 3)."""
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    c = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) * 0.5, -1.0, 1.0)
    theta = np.arccos(c)
    s = np.sin(theta)
    small = s < 1e-6
    factor = np.where(small, 0.5, theta / (2.0 * np.where(small, 1.0, s)))
    out = v * factor[:, None]
    near_pi = small & (c < 0)
    if near_pi.any():
        # At a half turn the antisymmetric part vanishes: the axis is the dominant column of R + I.
        M = R[near_pi] + np.eye(3)
        col = np.argmax(np.linalg.norm(M, axis=1), axis=1)
        axis = M[np.arange(len(M)), :, col]
        out[near_pi] = np.pi * axis / np.linalg.norm(axis, axis=1, keepdims=True)
    return out
