"""Inverse kinematics for many TCP targets at once: one damped least-squares descent per target,
in compiled code (:mod:`planner.compiled.ik_kernels`).

Why: the regrasp search weighs every grasp node by the CoM margin it will have, and that margin
depends on the arm's posture at the grasp, which only IK gives. Solved one by one (pinocchio) that
adds up over the ~1,400 nodes of a paper scenario; batched, an iteration of a target is a short
compiled loop (``benchmarks/bench_motion.py`` prints both rates).

The descent is the first attempt of :class:`planner.motion.ik.IkSolver` (same settings, seed, rest
posture, step cap, joint-limit handling and stall rule), in world-aligned errors and Jacobians
instead of LOCAL ``log6`` ones: the iterates differ, so a target can land on another solution
(the outcomes agree on ~98 % of random reachable targets, see the tests). Restarts are the
caller's: it passes one start configuration per target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.compiled.ik_kernels import descend
from planner.compiled.tree_kernels import ROOT_SLOT, TreeSpec, tree_from_rows
from planner.kinematics.batch import BatchKinematics
from planner.motion.ik_rules import (
    LIMIT_EPS,
    LIMIT_PASSES,
    STALL_IMPROVEMENT,
    STALL_ITERATIONS,
    IkSettings,
    active_columns,
)
from planner.robot.model import RobotModel
from planner.transforms import frame_from_z


@dataclass(frozen=True)
class BatchIkResult:
    """``q`` (N, nq): the solutions (rows where ``ok`` is False hold the last iterate); iterations per row,
    and the TCP's position (m) and rotation (rad) errors at the last iteration."""

    q: np.ndarray
    ok: np.ndarray
    iterations: np.ndarray
    pos_err: np.ndarray
    rot_err: np.ndarray

    def take(self, rows: np.ndarray) -> BatchIkResult:
        """The results of ``rows`` only."""
        return BatchIkResult(self.q[rows], self.ok[rows], self.iterations[rows], self.pos_err[rows], self.rot_err[rows])


@dataclass(frozen=True)
class _Chain:
    """The joints from the root to one hand's TCP, split where the first joint IK moves sits."""

    parent_jid: int  # the joint the first moving one hangs from: the same frame for every target
    tree: TreeSpec  # slot 0: the frame before the moving joints (given); then the moving joints to the TCP's
    step_slots: np.ndarray  # the slots of the joints IK moves, in the order of the active columns
    step_axes: np.ndarray  # their rotation axes (index of the frame's column)
    tcp_R0: np.ndarray  # the TCP's placement in the last slot's frame
    tcp_p0: np.ndarray


class BatchIk:
    """First-attempt IK of one hand for many targets, from one seed posture."""

    def __init__(self, robot: RobotModel, kinematics: BatchKinematics, settings: IkSettings):
        self.robot = robot
        self.kin = kinematics
        self.settings = settings
        self._chains: dict[tuple, _Chain] = {}

    def _chain(self, side: str, active: np.ndarray) -> _Chain:
        """The chain to ``side``'s TCP; every joint from the first active one on must be a revolute joint
        (about a frame axis or any axis), and every active joint on the chain.

        The compiled descent turns about a frame axis. A joint about another unit axis ``a`` is given to it
        as one about z in a frame turned by a fixed rotation C (C z = a) appended to its placement, and C's
        inverse is prepended to what hangs from it (the next joint's placement, or the TCP's): the same
        TCP poses and world joint axes, and for a robot whose joints all turn about frame axes nothing
        changes."""
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
            odd = [self.robot.joint_names[st.q_col] for st in moving
                   if st.kind not in ("R", "RU") or st.mult != 1.0 or st.offset != 0.0]
            if odd:
                raise ValueError(f"batch IK supports revolute joints only, not {', '.join(odd)}")
            slot = {st.jid: k + 1 for k, st in enumerate(moving)}
            slot[moving[0].parent] = 0
            rows = [st.slot(slot[st.parent]) for st in moving]
            axes = [st.axis_index for st in moving]
            _, tcp_R0, tcp_p0 = self.kin._frames[self.robot.spec.arms[side].tcp]
            tcp_R0, tcp_p0 = np.array(tcp_R0, dtype=float), np.array(tcp_p0, dtype=float)
            for k, st in enumerate(moving):
                if st.kind != "RU":
                    continue
                C = frame_from_z(np.asarray(st.axis, dtype=float) / np.linalg.norm(st.axis))
                rows[k] = {**rows[k], "R0": _rot(rows[k]["R0"]) @ C, "kind": "R", "axis_index": 2}
                axes[k] = 2
                if k + 1 < len(rows):
                    rows[k + 1] = {**rows[k + 1], "R0": C.T @ _rot(rows[k + 1]["R0"]),
                                   "p0": C.T @ np.asarray(rows[k + 1]["p0"], dtype=float)}
                else:
                    tcp_R0, tcp_p0 = C.T @ tcp_R0, C.T @ tcp_p0
            tree = tree_from_rows([ROOT_SLOT, *rows])
            axis_of = {st.jid: a for st, a in zip(moving, axes)}
            steps = [by_col[c] for c in active]
            self._chains[key] = _Chain(moving[0].parent, tree, np.array([slot[st.jid] for st in steps]),
                                       np.array([axis_of[st.jid] for st in steps]), np.ascontiguousarray(tcp_R0),
                                       np.ascontiguousarray(tcp_p0))
        return self._chains[key]

    def _parent_frame(self, chain: _Chain, base_pose: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World frame (R (3, 3, 1), p (3, 1)) of the joint before the moving ones, at configuration ``q``."""
        Rs, ps = self.kin.forward(base_pose, q[None])
        return Rs[chain.parent_jid], ps[chain.parent_jid]

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
        if not n:
            return BatchIkResult(q_out, np.zeros(0, dtype=bool), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0))
        parent = self._parent_frame(chain, np.asarray(base_pose, dtype=float), q_out[0])
        return self._descend(side, chain, parent, targets, q_out, rest_q, active)

    def _descend(self, side: str, chain: _Chain, parent: tuple[np.ndarray, np.ndarray], targets: np.ndarray,
                 Q: np.ndarray, rest_q: np.ndarray, active: np.ndarray) -> BatchIkResult:
        """Every target's descent from its row of ``Q`` (compiled: :func:`planner.compiled.ik_kernels.descend`)."""
        s = self.settings
        n = Q.shape[0]
        lo, hi = self.robot.lower[active], self.robot.upper[active]
        Q = np.array(Q, dtype=float, order="C")
        Q[:, active] = np.clip(Q[:, active], lo, hi)
        t = chain.tree
        R = np.empty((t.size, 3, 3, 1))
        p = np.empty((t.size, 3, 1))
        R[0], p[0] = parent
        ok = np.zeros(n, dtype=bool)
        its = np.zeros(n, dtype=np.int64)
        pos_err, rot_err = np.empty(n), np.empty(n)
        descend(np.ascontiguousarray(targets, dtype=float), Q, np.asarray(active, dtype=np.int64), lo, hi,
                np.asarray(rest_q, dtype=float)[active], t.parent, t.R0, t.p0, t.axis_index, t.col, chain.step_slots, chain.step_axes, chain.tcp_R0, chain.tcp_p0,
                s.pos_tol_m, s.rot_tol_rad, s.max_iterations, s.damping**2, s.nullspace_gain, s.max_step_rad,
                STALL_IMPROVEMENT, STALL_ITERATIONS, LIMIT_EPS, LIMIT_PASSES, R, p, ok, its, pos_err, rot_err)
        return BatchIkResult(Q, ok, its, pos_err, rot_err)


def _rot(R0: np.ndarray | None) -> np.ndarray:
    """A slot's fixed rotation (None: the identity)."""
    return np.eye(3) if R0 is None else np.asarray(R0, dtype=float)
