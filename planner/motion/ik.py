"""Inverse kinematics of the upper body: waist + one arm, or waist + both arms (handover).

The feet and pelvis are fixed by the stance, so IK only moves the waist and the
arm(s) that carry a target. Damped least squares on the TCP frame errors
(``log6`` of the local error, LOCAL Jacobians), with the joint limits enforced by
clamping after every step and a null-space pull towards a rest posture, so that
redundant joints stay near a natural posture instead of drifting to their limits.

Solves are seeded: the planner passes the nearest known solution (a neighbouring
grasp or key pose) as ``seed_q``; when that attempt fails, a few restarts from
random postures drawn with the caller's ``numpy.random.Generator`` follow, so
results are deterministic for a seed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
import pinocchio as pin
from scipy.linalg.lapack import dposv as _dposv

from planner.kinematics.batch import BatchKinematics
from planner.motion.ik_batch import BatchIk
from planner.motion.ik_rules import (
    LIMIT_EPS,
    LIMIT_PASSES,
    STALL_IMPROVEMENT,
    STALL_ITERATIONS,
    IkSettings,
    Side,
    active_columns,
)
from planner.robot.model import RobotModel
from planner.stability.stances import Stance


@dataclass(frozen=True)
class IkResult:
    """``q`` (full wire configuration) or None, with the reason of a failure."""

    q: np.ndarray | None
    reason: str | None
    code: str | None  # None, "OUT_OF_REACH", "NO_CONVERGENCE", "BAD_INPUT"
    iterations: int
    attempts: int
    pos_err_m: float
    rot_err_rad: float
    elapsed_s: float = field(default=0.0)

    @property
    def ok(self) -> bool:
        return self.q is not None


class IkSolver:
    """Upper-body IK for one robot in one stance (legs, neck and unused arm stay as in ``seed_q``).

    One hand's attempts run the compiled descent (:attr:`batch`), two hands' (a handover
    with the shared waist) pinocchio's LOCAL ``log6`` descent (:meth:`_attempt`). Holds a pinocchio
    ``Data`` scratch buffer: one solver per thread.
    """

    def __init__(self, robot: RobotModel, stance: Stance, settings: IkSettings | None = None,
                 kinematics: BatchKinematics | None = None):
        self.robot = robot
        self.stance = stance
        self.settings = settings or IkSettings()
        self.base_pose = np.asarray(stance.base_pose, dtype=float)
        self._model = robot.pin_model
        self._data = robot.create_data()
        self._tcp_fid = {side: robot.frame_id(arm.tcp) for side, arm in robot.spec.arms.items()}
        self._vcol = {
            name: int(self._model.idx_vs[self._model.getJointId(name)]) for name in robot.joint_names
        }
        self._reach = {side: self._arm_reach(side) for side in robot.spec.arms}
        idx_qs = list(self._model.idx_qs)
        self._pin_q_col = np.array([int(idx_qs[self._model.getJointId(n)]) for n in robot.joint_names], dtype=int)
        self.solves = 0
        self.total_time_s = 0.0
        self._kinematics = kinematics  # the batched forward pass its compiled descent uses (else its own)
        self._batch: BatchIk | None = None

    def active_indices(self, sides: Sequence[Side]) -> np.ndarray:
        """Wire columns IK moves for these hands: waist (if used) then each arm."""
        return active_columns(self.robot, self.settings, sides)

    def attempt_start(self, attempt: int, seed_q: np.ndarray, active: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Where attempt ``attempt`` starts: the seed, then alternately the seed perturbed and a uniform draw
        within the limits (the batched solver's callers repeat the first restart with this)."""
        if attempt == 0:
            return seed_q
        q0 = seed_q.copy()
        if attempt % 2 == 1:
            q0[active] = seed_q[active] + rng.normal(0.0, self.settings.restart_noise_rad, len(active))
        else:
            q0[active] = rng.uniform(self.robot.lower[active], self.robot.upper[active])
        return q0

    def _arm_reach(self, side: Side) -> tuple[int, float]:
        """(joint id of the arm's first joint, distance bound from that joint to the TCP)."""
        chain = self.robot.spec.arms[side].chain
        model = self._model
        first = model.getJointId(chain[0])
        fid = self._tcp_fid[side]
        # Sum of link offsets along the chain (an upper bound of the reach).
        total = 0.0
        for name in chain[1:]:
            total += float(np.linalg.norm(model.jointPlacements[model.getJointId(name)].translation))
        total += float(np.linalg.norm(model.frames[fid].placement.translation))
        return first, total

    def _errors(self, qp: np.ndarray, targets: Mapping[Side, pin.SE3], sides: Sequence[Side]) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Stacked local errors (6k,), Jacobian (6k, nv) and the worst position / rotation errors at pinocchio q ``qp``."""
        model, data = self._model, self._data
        pin.forwardKinematics(model, data, qp)
        errs, jacs = [], []
        pmax = rmax = 0.0
        for side in sides:
            fid = self._tcp_fid[side]
            cur = pin.updateFramePlacement(model, data, fid)
            iMd = cur.actInv(targets[side])
            e = pin.log6(iMd).vector
            dp = targets[side].translation - cur.translation
            pmax = max(pmax, math.sqrt(float(dp @ dp)))
            rmax = max(rmax, math.sqrt(float(e[3:] @ e[3:])))
            errs.append(e)
            J = pin.computeFrameJacobian(model, data, qp, fid, pin.LOCAL)
            # log6 error is (nearly) J dq for small errors; use the log Jacobian for accuracy further out.
            jacs.append(pin.Jlog6(iMd.inverse()) @ J)
        if len(sides) == 1:
            return errs[0], jacs[0], pmax, rmax
        return np.concatenate(errs), np.vstack(jacs), pmax, rmax

    def _attempt(self, q0: np.ndarray, rest: np.ndarray, targets: Mapping[Side, pin.SE3], sides: Sequence[Side], active: np.ndarray, vcols: np.ndarray) -> tuple[np.ndarray, int, float, float, bool]:
        """One damped least-squares descent; joints pinned at a limit that the step pushes further are frozen."""
        s = self.settings
        q = q0.copy()
        lo, hi = self.robot.lower[active], self.robot.upper[active]
        q[active] = np.clip(q[active], lo, hi)
        # Iterate on the pinocchio configuration: the active joints are plain (not mimic) joints.
        qp = self.robot.to_pin_q(self.base_pose, q)
        pcols = self._pin_q_col[active]
        lam2 = s.damping**2
        pmax = rmax = np.inf
        best_score, since_best = np.inf, 0
        lam2_eye = lam2 * np.eye(6 * len(sides))
        rest_a = rest[active]
        lo_eps, hi_eps = lo + LIMIT_EPS, hi - LIMIT_EPS
        it = 0
        for it in range(1, s.max_iterations + 1):
            e, J, pmax, rmax = self._errors(qp, targets, sides)
            if pmax <= s.pos_tol_m and rmax <= s.rot_tol_rad:
                return q, it, pmax, rmax, True
            score = pmax + 0.1 * rmax
            if score < best_score * (1.0 - STALL_IMPROVEMENT):
                best_score, since_best = score, 0
            else:
                since_best += 1
                if since_best >= STALL_ITERATIONS:
                    break
            Ja = J[:, vcols]
            qa = q[active]
            dq = self._dls_step(Ja, e, qa, rest_a, lam2_eye, s.nullspace_gain)
            at_lo, at_hi = qa <= lo_eps, qa >= hi_eps
            if at_lo.any() or at_hi.any():
                # Joints pinned at a limit that the step pushes further are frozen and the step re-solved.
                free = np.ones(len(active), dtype=bool)
                for _ in range(LIMIT_PASSES):
                    blocked = free & ((at_lo & (dq < 0)) | (at_hi & (dq > 0)))
                    if not blocked.any():
                        break
                    free &= ~blocked
                    dq = np.zeros(len(active))
                    if free.any():
                        dq[free] = self._dls_step(Ja[:, free], e, qa[free], rest_a[free], lam2_eye, s.nullspace_gain)
            big = np.abs(dq).max()
            if big > s.max_step_rad:
                dq *= s.max_step_rad / big
            qa_new = np.minimum(np.maximum(qa + dq, lo), hi)
            q[active] = qa_new
            qp[pcols] = qa_new
        e, J, pmax, rmax = self._errors(qp, targets, sides)
        return q, it, pmax, rmax, bool(pmax <= s.pos_tol_m and rmax <= s.rot_tol_rad)

    @property
    def batch(self) -> BatchIk:
        """This solver's one-hand descent for many targets at once (compiled, :mod:`planner.motion.ik_batch`, same
        settings), built on first use; its own one-hand attempts run through it too."""
        if self._batch is None:
            self._batch = BatchIk(self.robot, self._kinematics or BatchKinematics(self.robot), self.settings)
        return self._batch

    def _attempt_one_hand(self, side: Side, q0: np.ndarray, rest: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, int, float, float, bool]:
        """:meth:`_attempt` for one hand, compiled (:attr:`batch`): the same descent in world-aligned errors and
        the geometric Jacobian, without pinocchio's per-call overhead."""
        r = self.batch.solve(side, np.asarray(target, dtype=float)[None], self.base_pose, q0, rest)
        return r.q[0], int(r.iterations[0]), float(r.pos_err[0]), float(r.rot_err[0]), bool(r.ok[0])

    @staticmethod
    def _dls_step(Ja: np.ndarray, e: np.ndarray, qa: np.ndarray, rest_a: np.ndarray, lam2_eye: np.ndarray, gain: float) -> np.ndarray:
        """Damped least-squares step towards the error plus the null-space pull to the rest posture."""
        # dq = J^T (J J^T + lambda^2 I)^-1 (e - J pull) + pull. The damped matrix is symmetric positive
        # definite: LAPACK's Cholesky solve, called directly, costs a third of numpy.linalg.solve here.
        A = Ja @ Ja.T + lam2_eye
        pull = gain * (rest_a - qa) if gain > 0 else None
        rhs = e - Ja @ pull if pull is not None else e
        _, x, info = _dposv(A, rhs)
        if info != 0:
            x = np.linalg.solve(A, rhs)
        return Ja.T @ x + pull if pull is not None else Ja.T @ x

    def solve(
        self,
        targets: Mapping[Side, np.ndarray],
        seed_q: np.ndarray,
        rng: np.random.Generator,
        rest_q: np.ndarray | None = None,
    ) -> IkResult:
        """Move waist + the targeted arm(s) so each TCP reaches its world pose (4, 4).

        ``seed_q`` is a full wire configuration: the first attempt starts there and
        every joint IK does not move keeps its value. ``rest_q`` (default: the
        stance posture) is what the null-space pull aims at.
        """
        t0 = time.perf_counter()
        s = self.settings
        sides = [side for side in ("left", "right") if side in targets]
        if not sides or len(sides) != len(targets):
            return self._fail(None, "BAD_INPUT", f"targets must be keyed by 'left' and/or 'right', got {sorted(targets)}", 0, 0, t0)
        seed_q = np.asarray(seed_q, dtype=float)
        if seed_q.shape != (self.robot.nq,) or not np.all(np.isfinite(seed_q)):
            return self._fail(None, "BAD_INPUT", f"seed_q must be {self.robot.nq} finite values", 0, 0, t0)
        se3: dict[Side, pin.SE3] = {}
        for side in sides:
            T = np.asarray(targets[side], dtype=float)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                return self._fail(None, "BAD_INPUT", f"{side} target must be a finite 4x4 transform", 0, 0, t0)
            R = T[:3, :3]
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
                return self._fail(None, "BAD_INPUT", f"{side} target rotation is not orthonormal", 0, 0, t0)
            se3[side] = pin.SE3(R, T[:3, 3])
        rest = np.asarray(rest_q if rest_q is not None else self.stance.q, dtype=float)
        active = self.active_indices(sides)
        vcols = np.array([self._vcol[self.robot.joint_names[i]] for i in active], dtype=int)

        # Quick reach test from the shoulder at the seed posture (the waist moves the shoulder only a little).
        pin.forwardKinematics(self._model, self._data, self.robot.to_pin_q(self.base_pose, seed_q))
        for side in sides:
            jfirst, reach = self._reach[side]
            d = float(np.linalg.norm(se3[side].translation - self._data.oMi[jfirst].translation))
            waist_slack = 0.35 if s.use_waist else 0.0  # the waist can bring the shoulder this much closer
            if d > reach * s.reach_slack + waist_slack:
                return self._fail(None, "OUT_OF_REACH", f"{side} TCP target is {d:.3f} m from the shoulder, beyond the arm's reach {reach:.3f} m", 0, 0, t0)

        total_it = 0
        best = (np.inf, np.inf)
        for attempt in range(s.restarts + 1):
            q0 = self.attempt_start(attempt, seed_q, active, rng)
            if len(sides) == 1:
                q, it, pe, re, ok = self._attempt_one_hand(sides[0], q0, rest, targets[sides[0]])
            else:
                q, it, pe, re, ok = self._attempt(q0, rest, se3, sides, active, vcols)
            total_it += it
            if ok:
                elapsed = time.perf_counter() - t0
                self.solves += 1
                self.total_time_s += elapsed
                return IkResult(q=q, reason=None, code=None, iterations=total_it, attempts=attempt + 1, pos_err_m=pe, rot_err_rad=re, elapsed_s=elapsed)
            if pe + re < best[0] + best[1]:
                best = (pe, re)
            if best[0] > s.restart_max_residual_m:
                break
        return self._fail(
            best, "NO_CONVERGENCE",
            f"IK for {'+'.join(sides)} did not converge within the joint limits after {attempt + 1} attempts "
            f"(best residual {best[0] * 1000:.1f} mm, {best[1]:.3f} rad)",
            total_it, attempt + 1, t0,
        )

    def solve_arm(self, side: Side, T_world_tcp: np.ndarray, seed_q: np.ndarray, rng: np.random.Generator, rest_q: np.ndarray | None = None) -> IkResult:
        """Waist + one arm to one TCP pose."""
        return self.solve({side: T_world_tcp}, seed_q, rng, rest_q)

    def solve_both(self, T_left: np.ndarray, T_right: np.ndarray, seed_q: np.ndarray, rng: np.random.Generator, rest_q: np.ndarray | None = None) -> IkResult:
        """Waist + both arms (handover): two TCP poses, one shared waist."""
        return self.solve({"left": T_left, "right": T_right}, seed_q, rng, rest_q)

    def _fail(self, best: tuple[float, float] | None, code: str, reason: str, iterations: int, attempts: int, t0: float) -> IkResult:
        elapsed = time.perf_counter() - t0
        self.solves += 1
        self.total_time_s += elapsed
        pe, re = best if best is not None else (np.inf, np.inf)
        return IkResult(q=None, reason=reason, code=code, iterations=iterations, attempts=attempts, pos_err_m=float(pe), rot_err_rad=float(re), elapsed_s=elapsed)

    def tcp_pose(self, q: np.ndarray, side: Side) -> np.ndarray:
        """World TCP pose (4, 4) of a configuration."""
        pin.forwardKinematics(self._model, self._data, self.robot.to_pin_q(self.base_pose, np.asarray(q, dtype=float)))
        return pin.updateFramePlacement(self._model, self._data, self._tcp_fid[side]).homogeneous.copy()


def key_pose_targets(T_world_tcp_grasp: np.ndarray, approach_m: float = 0.05, lift_m: float = 0.05) -> dict[str, np.ndarray]:
    """The TCP targets of one grasp node: ``pregrasp`` (backed off along the approach axis, the TCP z),
    ``grasp``, and ``lift`` (raised along the world z), each a (4, 4) world pose."""
    T = np.asarray(T_world_tcp_grasp, dtype=float)
    pre = T.copy()
    pre[:3, 3] = T[:3, 3] - approach_m * T[:3, 2]
    lift = T.copy()
    lift[2, 3] += lift_m
    return {"pregrasp": pre, "grasp": T.copy(), "lift": lift}
