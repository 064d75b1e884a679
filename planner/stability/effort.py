"""Static joint torques and grip loads of robot states holding an object, in batches.

What the robot must hold still, as the plan file's contract defines it: gravity on every link
and on the held object (its weight at its CoM, carried by the holding hand's TCP link; half by
each hand while both hold), balanced by 6D contact wrenches at the origins of the soles in
contact, the wrenches chosen with the minimum 2-norm of the stacked [force; moment] vector
(rotating a sole's frame keeps each 3-vector's norm, so the minimum is the same in world axes).
The joint torque is then what the joint transmits to the part of the tree beyond it:
``tau_j = -a_j . sum over the subtree of (p - o_j) x F + M`` for a revolute joint (axis ``a_j``
at ``o_j``), ``-a_j . sum F`` for a prismatic one. This equals pinocchio's RNEA at zero velocity
and acceleration with the contact wrenches as external forces (the tests compare to 1e-6).

With the feet fixed by the stance the contact points are constant, so the minimum-norm wrenches
are one constant (12, 6) matrix times the total gravity wrench: the only state-dependent inputs
are the joint frames (the batched tree walk of :mod:`planner.kinematics.batch`) and the system
CoM. The subtree sums and the axis projections run in one compiled loop.

Grip (a hand with jaws; a rigid hand has none): the share of the object's weight a hand carries
against the two jaw contacts' friction (``2 * friction * force_n``), and the moment of that share
about the jaw's closing axis (the TCP's y axis, through the TCP) against ``2 * friction * force_n
* patch_radius_m``. Ratios above 1 are over the limit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from planner.compiled.jit import njit
from planner.kinematics.batch import BatchKinematics, frames_block
from planner.kinematics.joint_table import joint_table
from planner.robot.model import RobotModel
from planner.stability.stances import Stance

GRAVITY = 9.81
Holding = Literal["none", "left", "right", "both"]
_SIDES_OF = {"none": (), "left": ("left",), "right": ("right",), "both": ("left", "right")}


@dataclass(frozen=True)
class EffortTable:
    """What the torque loop needs of one robot model, derived once (kept with the model).

    Per pinocchio joint id: parent, whether revolute, the axis in the joint frame, the link's mass
    and lever; the checked joints (every wire joint but the jaws, mimic joints folded into their
    master through the multiplier), their limits and where each limit came from.
    """

    parent: np.ndarray  # (J,) int64
    revolute: np.ndarray  # (J,) int64: 1 revolute, 0 prismatic or fixed/root
    axis: np.ndarray  # (J, 3)
    mass: np.ndarray  # (J,)
    lever: np.ndarray  # (J, 3)
    checked: tuple[str, ...]
    #: (K, J) torque of each checked wire joint from the per-pinocchio-joint torques (mimic folding)
    fold: np.ndarray
    limit: np.ndarray  # (K,) N*m or N
    limit_source: dict[str, str]


def effort_limits(robot: RobotModel) -> dict[str, float]:
    """Effort limit per wire joint: the spec's ``effort_limits`` over the URDF's ``<limit effort>``."""
    table = effort_table(robot)
    return dict(zip(table.checked, table.limit.tolist()))


def effort_table(robot: RobotModel) -> EffortTable:
    return robot.derived("effort_table", lambda: _build_table(robot))


def jaw_joints(robot: RobotModel) -> set[str]:
    """The wire joints that open and close the jaws (left out of the torque check)."""
    return {arm.gripper.joint for arm in robot.spec.arms.values() if arm.gripper is not None}


def _build_table(robot: RobotModel) -> EffortTable:
    table = joint_table(robot)
    model = robot.pin_model
    rows = table.rows
    J = table.njoints
    parent = np.array([max(r.parent, 0) for r in rows], dtype=np.int64)
    revolute = np.array([1 if r.kind in ("R", "RU") else 0 for r in rows], dtype=np.int64)
    axis = np.array([r.axis for r in rows], dtype=float).reshape(J, 3)
    prismatic = np.array([r.kind in ("P", "PU") for r in rows])
    mass = np.array([r.mass for r in rows], dtype=float)
    lever = np.array([r.lever for r in rows], dtype=float).reshape(J, 3)
    jaws = jaw_joints(robot)
    checked = [n for n in robot.joint_names if n not in jaws]
    col = {n: i for i, n in enumerate(robot.joint_names)}
    fold = np.zeros((len(checked), J))
    for k, name in enumerate(checked):
        for r in rows[2:]:
            src, mult, _ = r.source
            if src == col[name]:
                fold[k, r.jid] = mult
    overrides = dict(robot.spec.effort_limits)
    unknown = sorted(set(overrides) - set(robot.joint_names))
    if unknown:
        raise ValueError(f"robot {robot.name!r}: effort_limits names unknown joints: {', '.join(unknown)}")
    limits, source = [], {}
    eff = np.array(model.effortLimit)
    for name in checked:
        if name in overrides:
            limits.append(float(overrides[name]))
            source[name] = "spec effort_limits"
        else:
            v = float(eff[model.idx_vs[model.getJointId(name)]])
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"robot {robot.name!r}: joint {name!r} has no effort limit in the URDF; "
                                 "give one in the spec's effort_limits")
            limits.append(v)
            source[name] = "URDF <limit effort>"
    # prismatic joints use their axis in the force projection, revolute ones in the moment projection
    revolute = np.where(prismatic, -1, revolute).astype(np.int64)
    return EffortTable(parent=parent, revolute=revolute, axis=axis, mass=mass, lever=lever, checked=tuple(checked),
                       fold=fold, limit=np.array(limits, dtype=float), limit_source=source)


@dataclass(frozen=True)
class GripLimits:
    """A jaw hand's grip: friction coefficient, squeeze force per jaw (N), contact patch radius (m)."""

    friction: float
    force_n: float
    patch_radius_m: float

    @property
    def force_cap(self) -> float:
        return 2.0 * self.friction * self.force_n

    @property
    def moment_cap(self) -> float:
        return 2.0 * self.friction * self.force_n * self.patch_radius_m


@dataclass(frozen=True)
class LimitBatch:
    """Per state: joint torques (N, K), ``effort_ratio`` (N,) = max |tau| / limit, ``grip_ratio`` (N,)
    (0 where nothing is held by a jaw hand), and the first failing cause (None, "effort" or "grip")."""

    torque: np.ndarray
    effort_ratio: np.ndarray
    grip_ratio: np.ndarray

    @property
    def effort_ok(self) -> np.ndarray:
        return self.effort_ratio <= 1.0

    @property
    def grip_ok(self) -> np.ndarray:
        return self.grip_ratio <= 1.0

    @property
    def ok(self) -> np.ndarray:
        return self.effort_ok & self.grip_ok


class EffortEvaluator:
    """Static torques and grip ratios of states of one robot in one stance holding one object.

    Owns its scratch (the batched kinematics' buffers); one per planning task or survey worker.
    """

    def __init__(self, robot: RobotModel, stance: Stance, object_mass: float, com_local: np.ndarray,
                 grip: dict[str, GripLimits | None] | None = None):
        self.robot = robot
        self.table = effort_table(robot)
        self.base_pose = np.asarray(stance.base_pose, dtype=float)
        self.object_mass = float(object_mass)
        self.com_local = np.asarray(com_local, dtype=float)
        self.kin = BatchKinematics(robot)
        frames = joint_table(robot).frames
        self.tcp = {side: arm.tcp for side, arm in robot.spec.arms.items()}
        self.tcp_joint = {side: frames[f][0] for side, f in self.tcp.items()}
        self.grip = grip if grip is not None else default_grip(robot)
        soles = [f.frame for f in stance.feet if f.in_contact]
        if not soles:
            raise ValueError("a stance with no sole in contact cannot hold the robot up")
        self.contact_joint = np.array([frames[f][0] for f in soles], dtype=np.int64)
        # where the soles are at the stance's posture (the legs never move within a stance)
        Rs, ps = self.kin.forward(self.base_pose, stance.q[None])
        self.contact_point = np.array([self.kin.frame(Rs, ps, f)[1][0] for f in soles])  # (C, 3) world
        self._wrench_map = min_norm_wrench_map(self.contact_point)

    def evaluate(self, Q: np.ndarray, holding: Holding, object_pose: np.ndarray | None = None,
                 T_tcp_obj: np.ndarray | None = None, frames: tuple[list, list] | None = None) -> LimitBatch:
        """Torques and grip of states Q (N, n) while ``holding``; the object's world poses (N, 4, 4), or
        its pose in the holding TCP frame (``T_tcp_obj``, left hand's TCP while both hold). ``frames``: the
        states' :meth:`BatchKinematics.forward` at the stance's base pose, when the caller has it (the
        state checker computes it once for this check and the collision check)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        n = len(Q)
        Rs, ps = frames if frames is not None else self.kin.forward(self.base_pose, Q)
        R, p = frames_block(Rs), frames_block(ps)
        sides = _SIDES_OF[holding]
        m_o = self.object_mass if sides else 0.0
        tcp = {side: self.kin.frame(Rs, ps, self.tcp[side]) for side in sides}
        if sides:
            if object_pose is None:
                if T_tcp_obj is None:
                    raise ValueError("a held object needs its world poses or its pose in the TCP frame")
                Rt, pt = tcp["left" if holding == "both" else holding]
                c_obj = pt + Rt @ (T_tcp_obj[:3, :3] @ self.com_local + T_tcp_obj[:3, 3])
            else:
                object_pose = np.asarray(object_pose, dtype=float).reshape(n, 4, 4)
                c_obj = object_pose[:, :3, :3] @ self.com_local + object_pose[:, :3, 3]
        else:
            c_obj = np.zeros((n, 3))
        t = self.table
        ext_joint = [*self.contact_joint.tolist(), *[self.tcp_joint[s] for s in sides]]
        share = m_o / len(sides) if sides else 0.0
        tau = np.empty((t.parent.size, n))
        _static_torques(R, p, t.parent, t.revolute, t.axis, t.mass, t.lever, np.array(ext_joint, dtype=np.int64),
                        self.contact_point, self._wrench_map, np.ascontiguousarray(c_obj.T), m_o, share, GRAVITY, tau)
        torque = (t.fold @ tau).T
        effort_ratio = np.abs(torque / t.limit).max(axis=1) if t.limit.size else np.zeros(n)
        grip_ratio = np.zeros(n)
        for side in sides:
            g = self.grip.get(side)
            if g is None or m_o == 0.0:
                continue
            Rt, pt = tcp[side]
            load = share * GRAVITY
            # moment of the share's weight (0, 0, -load) at c_obj about the TCP: r x F, projected on the TCP's y axis
            r = c_obj - pt
            moment = np.abs(load * (r[:, 1] * Rt[:, 0, 1] - r[:, 0] * Rt[:, 1, 1]))
            grip_ratio = np.maximum(grip_ratio, np.maximum(load / g.force_cap, moment / g.moment_cap))
        return LimitBatch(torque=torque, effort_ratio=effort_ratio, grip_ratio=grip_ratio)

    def contact_wrenches(self, com: np.ndarray, total_mass: float) -> np.ndarray:
        """Minimum-norm contact wrenches (N, C, 6) [force; moment about the sole origin], world axes."""
        com = np.atleast_2d(com)
        W = total_mass * GRAVITY
        b = np.zeros((len(com), 6))
        b[:, 2] = W
        b[:, 3] = com[:, 1] * W
        b[:, 4] = -com[:, 0] * W
        return (b @ self._wrench_map.T).reshape(len(com), -1, 6)


def default_grip(robot: RobotModel) -> dict[str, GripLimits | None]:
    """Each hand's grip from the spec (None: no grip check, a rigid hand or no grip figures)."""
    g = robot.spec.grip
    out: dict[str, GripLimits | None] = {}
    for side, arm in robot.spec.arms.items():
        out[side] = None if (g is None or arm.gripper is None) else GripLimits(g.friction, g.force_n, g.patch_radius_m)
    return out


def min_norm_wrench_map(points: np.ndarray) -> np.ndarray:
    """(6C, 6) map from the wrench the contacts must supply ([F; moment about the world origin]) to the
    stacked per-contact [f; m] (m about each contact point) of minimum 2-norm."""
    C = len(points)
    A = np.zeros((6, 6 * C))
    for c, pt in enumerate(points):
        A[:3, 6 * c:6 * c + 3] = np.eye(3)
        A[3:, 6 * c:6 * c + 3] = _skew(pt)
        A[3:, 6 * c + 3:6 * c + 6] = np.eye(3)
    return np.linalg.pinv(A)


def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


@njit(cache=True, nogil=True)
def _static_torques(R, p, parent, revolute, axis, mass, lever, ext_joint, contact_point, wrench_map, c_obj, m_obj,
                    share, g, tau):  # pragma: no cover - compiled
    """Fill tau (J, N): per pinocchio joint, the static torque (see the module docstring)."""
    J = parent.shape[0]
    N = R.shape[3]
    C = contact_point.shape[0]
    F = np.zeros((J, 3, N))
    M = np.zeros((J, 3, N))  # moment about the world origin
    com_m = np.zeros((3, N))
    total = 0.0
    for k in range(1, J):
        m = mass[k]
        if m <= 0.0:
            continue
        total += m
        for n in range(N):
            cx = p[k, 0, n] + R[k, 0, 0, n] * lever[k, 0] + R[k, 0, 1, n] * lever[k, 1] + R[k, 0, 2, n] * lever[k, 2]
            cy = p[k, 1, n] + R[k, 1, 0, n] * lever[k, 0] + R[k, 1, 1, n] * lever[k, 1] + R[k, 1, 2, n] * lever[k, 2]
            com_m[0, n] += m * cx
            com_m[1, n] += m * cy
            # force (0, 0, -m g) at c: moment c x F = (-cy m g, cx m g, 0)
            F[k, 2, n] -= m * g
            M[k, 0, n] -= cy * m * g
            M[k, 1, n] += cx * m * g
    # the held object's weight, a share through each holding TCP's joint
    for e in range(C, ext_joint.shape[0]):
        k = ext_joint[e]
        for n in range(N):
            F[k, 2, n] -= share * g
            M[k, 0, n] -= c_obj[1, n] * share * g
            M[k, 1, n] += c_obj[0, n] * share * g
    if ext_joint.shape[0] > C:
        total_o = m_obj
    else:
        total_o = 0.0
    W = (total + total_o) * g
    b = np.zeros(6)
    for n in range(N):
        # the gravity wrench about the origin the contacts must cancel: F = (0, 0, W), moment = c x F
        mx = com_m[0, n] + total_o * c_obj[0, n]
        my = com_m[1, n] + total_o * c_obj[1, n]
        b[0] = 0.0
        b[1] = 0.0
        b[2] = W
        b[3] = my * g
        b[4] = -mx * g
        b[5] = 0.0
        for c in range(C):
            k = ext_joint[c]
            w = np.zeros(6)
            for i in range(6):
                v = 0.0
                for j in range(6):
                    v += wrench_map[6 * c + i, j] * b[j]
                w[i] = v
            px, py, pz = contact_point[c, 0], contact_point[c, 1], contact_point[c, 2]
            F[k, 0, n] += w[0]
            F[k, 1, n] += w[1]
            F[k, 2, n] += w[2]
            M[k, 0, n] += py * w[2] - pz * w[1] + w[3]
            M[k, 1, n] += pz * w[0] - px * w[2] + w[4]
            M[k, 2, n] += px * w[1] - py * w[0] + w[5]
    for k in range(J - 1, 1, -1):  # children after parents: accumulate each subtree into its parent
        a = parent[k]
        for i in range(3):
            for n in range(N):
                F[a, i, n] += F[k, i, n]
                M[a, i, n] += M[k, i, n]
    for k in range(J):
        for n in range(N):
            tau[k, n] = 0.0
    for k in range(2, J):
        if revolute[k] == 0:
            continue
        for n in range(N):
            ax = R[k, 0, 0, n] * axis[k, 0] + R[k, 0, 1, n] * axis[k, 1] + R[k, 0, 2, n] * axis[k, 2]
            ay = R[k, 1, 0, n] * axis[k, 0] + R[k, 1, 1, n] * axis[k, 1] + R[k, 1, 2, n] * axis[k, 2]
            az = R[k, 2, 0, n] * axis[k, 0] + R[k, 2, 1, n] * axis[k, 1] + R[k, 2, 2, n] * axis[k, 2]
            if revolute[k] > 0:
                ox, oy, oz = p[k, 0, n], p[k, 1, n], p[k, 2, n]
                mx = M[k, 0, n] - (oy * F[k, 2, n] - oz * F[k, 1, n])
                my = M[k, 1, n] - (oz * F[k, 0, n] - ox * F[k, 2, n])
                mz = M[k, 2, n] - (ox * F[k, 1, n] - oy * F[k, 0, n])
                tau[k, n] = -(ax * mx + ay * my + az * mz)
            else:
                tau[k, n] = -(ax * F[k, 0, n] + ay * F[k, 1, n] + az * F[k, 2, n])
