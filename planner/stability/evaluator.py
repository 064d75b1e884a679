"""Stability of robot states with a held object: system CoM, margin and object pose, in batches.

The planner's T-RRT and the stability survey evaluate tens of thousands of
configurations of one robot in one stance. With the stance fixed, the feet and
pelvis never move, and every joint that a batch does not vary (legs, neck, the
idle arm, the jaws) only carries its links rigidly along with the nearest moving
joint above it. :class:`ReducedKinematics` exploits this: it folds every fixed
part into a constant world mass or into the composite body of the moving joint
it hangs from, so a batch walks only the moving joints (12 for waist + one arm
instead of 39 pinocchio joints). It is exact, not an approximation: the tests
compare it with pinocchio's ``centerOfMass`` to 1e-9.

The system CoM is the paper's equation 1 (:func:`planner.stability.support_polygon.system_com`)
and the margin is the signed distance of its ground projection to the support
polygon edge (:meth:`planner.stability.support_polygon.SupportPolygon.margin`).

Grasp convention: a :class:`HoldSpec` carries ``T_obj_tcp``, the pose of the
holding hand's TCP frame expressed in the object frame (a grasp as stored per
object). The object's world pose is then ``T_world_tcp @ inv(T_obj_tcp)``.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np
import pinocchio as pin

from planner.kinematics.batch import _affine
from planner.robot.model import RobotModel
from planner.stability.support_polygon import system_com
from planner.stability.stances import Stance
from planner.transforms import inverse
from planner.compiled.tree_kernels import tree_spec, walk, weighted_sum

HoldSide = Literal["left", "right", "both"]
#: How many reduced kinematic trees one evaluator keeps (one per active joint set / fixed posture).
REDUCED_CACHE_SIZE = 16
#: Batches up to this size go through pinocchio state by state (no reduced-tree set-up).
SMALL_BATCH = 16


@dataclass(frozen=True)
class HoldSpec:
    """What a state holds: which hand(s), and the grasp that fixes the object to the hand.

    ``T_obj_tcp`` is the (4, 4) pose of the holding TCP in the object frame; for
    ``side == "both"`` it is the left hand's grasp, which fixes the object pose
    (the right hand's grasp only matters to IK and collision).
    """

    side: HoldSide
    T_obj_tcp: np.ndarray

    def __post_init__(self) -> None:
        if self.side not in ("left", "right", "both"):
            raise ValueError(f"holding side {self.side!r} is not one of left, right, both")
        T = np.asarray(self.T_obj_tcp, dtype=float)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"T_obj_tcp must be a finite 4x4 transform, got shape {T.shape}")
        # Orthonormal with determinant 1, to 1e-6. Plain arithmetic: the planner builds one per probed
        # giver posture (~900 per dual-arm survey), where np.allclose and det cost 0.1 ms each.
        R = T[:3, :3]
        (a, b, c), (d, e, f), (g, h, i) = R.tolist()
        det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
        if float(np.abs(R @ R.T - _I3).max()) > 1e-6 or abs(det - 1.0) > 1e-6:
            raise ValueError("T_obj_tcp's rotation block is not a rotation matrix")
        object.__setattr__(self, "T_obj_tcp", T)

    @property
    def tcp_side(self) -> Literal["left", "right"]:
        """The hand whose TCP carries the object frame."""
        return "left" if self.side == "both" else self.side

    @property
    def T_tcp_obj(self) -> np.ndarray:
        """The object frame expressed in the holding TCP frame."""
        return inverse(self.T_obj_tcp)

    @property
    def label(self) -> str:
        return self.side


@dataclass(frozen=True)
class StateBatch:
    """Evaluated states: ``robot_com`` and ``com`` (N, 3), ``margin`` and ``stable`` (N,), ``object_pose`` (N, 4, 4) or None."""

    robot_com: np.ndarray
    com: np.ndarray
    margin: np.ndarray
    stable: np.ndarray
    object_pose: np.ndarray | None

    def __len__(self) -> int:
        return len(self.margin)


@dataclass(frozen=True)
class StateOne:
    """One evaluated state (the fast single-state path)."""

    robot_com: np.ndarray
    com: np.ndarray
    margin: float
    stable: bool
    object_pose: np.ndarray | None


@dataclass(frozen=True)
class _Step:
    jid: int
    anchor: int  # index of the parent step, -1 for the fixed world part
    R_rel: np.ndarray | None  # None: identity
    p_rel: np.ndarray
    kind: str  # "R", "P", "RU", "PU"
    axis_index: int
    axis: np.ndarray
    col: int
    mult: float
    offset: float
    mass: float
    lever: np.ndarray  # composite CoM in the joint frame


_KINDS = {
    "JointModelRX": ("R", 0), "JointModelRY": ("R", 1), "JointModelRZ": ("R", 2),
    "JointModelPX": ("P", 0), "JointModelPY": ("P", 1), "JointModelPZ": ("P", 2),
    "JointModelRevoluteUnaligned": ("RU", -1), "JointModelPrismaticUnaligned": ("PU", -1),
}


class ReducedKinematics:
    """Exact batched CoM and frame poses when only ``active`` wire columns vary.

    Built once for a base pose, a reference configuration (giving the values of
    every fixed joint) and the active columns; evaluating a batch then costs a
    few vector operations per active joint.
    """

    def __init__(
        self,
        robot: RobotModel,
        base_pose: np.ndarray,
        q_ref: np.ndarray,
        active: Sequence[int],
        frames: Sequence[str] = (),
        data: pin.Data | None = None,
    ):
        """``data``: a pinocchio scratch buffer to reuse (creating one costs more than the rest)."""
        st = _statics(robot)
        if data is None:
            data = robot.pin_model.createData()
        self.robot = robot
        self.active = np.array(sorted(set(int(a) for a in active)), dtype=int)
        self.q_ref = np.array(q_ref, dtype=float)
        active_set = set(self.active.tolist())
        pin.forwardKinematics(robot.pin_model, data, robot.to_pin_q(np.asarray(base_pose, float), self.q_ref))
        oMi = list(data.oMi)  # one copy of the vector (each indexed access would copy it again)

        # anchor[j]: step index of the nearest moving joint at or above j; -1 = fixed in the world.
        anchor = [-1] * st.njoints
        steps_raw: list[dict] = []
        for jid in range(1, st.njoints):
            parent_anchor = anchor[st.parents[jid]] if jid > 1 else -1
            col, mult, off = st.source[jid]
            if jid < 2 or col not in active_set:
                anchor[jid] = parent_anchor
                continue
            kind, ax, axis = st.kinds[jid]
            if kind is None:
                raise ValueError(f"joint {st.names[jid]!r} of type {axis} is not supported")
            parent_frame = oMi[steps_raw[parent_anchor]["jid"]] if parent_anchor >= 0 else pin.SE3.Identity()
            rel = parent_frame.actInv(oMi[st.parents[jid]] * st.placements[jid])
            R_rel = np.array(rel.rotation)
            steps_raw.append(dict(
                jid=jid, anchor=parent_anchor, R_rel=None if np.abs(R_rel - _I3).max() < 1e-14 else R_rel,
                p_rel=np.array(rel.translation), kind=kind, axis_index=ax, axis=axis,
                col=col, mult=mult, offset=off, mass=0.0, moment=np.zeros(3),
            ))
            anchor[jid] = len(steps_raw) - 1

        fixed_mass, fixed_moment = 0.0, np.zeros(3)
        for jid in range(1, st.njoints):
            m, lever = st.masses[jid]
            if m <= 0.0:
                continue
            c_world = oMi[jid].act(lever)
            a = anchor[jid]
            if a < 0:
                fixed_mass += m
                fixed_moment += m * c_world
            else:
                s = steps_raw[a]
                s["mass"] += m
                s["moment"] += m * oMi[s["jid"]].actInv(c_world)
        self.total_mass = float(fixed_mass + sum(s["mass"] for s in steps_raw))
        self._fixed_moment = fixed_moment
        self._steps = [
            _Step(
                jid=s["jid"], anchor=s["anchor"], R_rel=s["R_rel"], p_rel=s["p_rel"], kind=s["kind"],
                axis_index=s["axis_index"], axis=s["axis"], col=s["col"], mult=s["mult"], offset=s["offset"],
                mass=s["mass"], lever=s["moment"] / s["mass"] if s["mass"] > 0 else np.zeros(3),
            )
            for s in steps_raw
        ]
        steps = self._steps
        self._tree = tree_spec(parent=[s.anchor for s in steps], R0=[s.R_rel for s in steps], p0=[s.p_rel for s in steps],
                               kind=[s.kind for s in steps], axis_index=[max(s.axis_index, 0) for s in steps],
                               axis=[s.axis for s in steps], col=[s.col for s in steps], mult=[s.mult for s in steps],
                               offset=[s.offset for s in steps])
        self._mass_slots = np.array([k for k, s in enumerate(steps) if s.mass > 0.0], dtype=np.int64)
        self._slot_mass = np.array([steps[k].mass for k in self._mass_slots], dtype=float)
        self._slot_lever = np.array([steps[k].lever for k in self._mass_slots], dtype=float).reshape(-1, 3)
        self._frames: dict[str, tuple[int, np.ndarray, np.ndarray]] = {}
        for name in frames:
            parent_joint, placement = st.frame(robot, name)
            world = oMi[parent_joint] * placement
            a = anchor[parent_joint]
            rel = oMi[self._steps[a].jid].actInv(world) if a >= 0 else world
            self._frames[name] = (a, np.array(rel.rotation), np.array(rel.translation))

    @property
    def frames(self) -> tuple[str, ...]:
        return tuple(self._frames)

    def _forward(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (S, 3, 3, N) and positions (S, 3, N) of every moving joint frame."""
        n = Q.shape[0]
        R = np.empty((self._tree.size, 3, 3, n))
        p = np.empty((self._tree.size, 3, n))
        walk(self._tree, Q, R, p)
        return R, p

    def _com(self, Rs: np.ndarray, ps: np.ndarray) -> np.ndarray:
        return weighted_sum(Rs, ps, self._mass_slots, self._slot_mass, self._slot_lever, self._fixed_moment, self.total_mass)

    def _frame(self, Rs: list[np.ndarray], ps: list[np.ndarray], name: str, n: int) -> tuple[np.ndarray, np.ndarray]:
        a, R0, p0 = self._frames[name]
        if a < 0:
            return np.repeat(R0[None], n, axis=0), np.repeat(p0[None], n, axis=0)
        R = np.einsum("ijn,jk->nik", Rs[a], R0)
        p = _affine(ps[a], Rs[a], p0).T
        return R, p

    def com(self, Q: np.ndarray) -> np.ndarray:
        """Robot CoM in the world, (N, 3)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        Rs, ps = self._forward(Q)
        return self._com(Rs, ps)

    def com_and_frames(self, Q: np.ndarray, frames: Sequence[str] | None = None) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
        """Robot CoM (N, 3) and world (R (N, 3, 3), p (N, 3)) of the requested frames (default: all built)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        n = Q.shape[0]
        Rs, ps = self._forward(Q)
        names = self.frames if frames is None else frames
        return self._com(Rs, ps), {f: self._frame(Rs, ps, f, n) for f in names}


_I3 = np.eye(3)


@dataclass(frozen=True)
class _Statics:
    """Per-robot model data read once: pinocchio's vector accessors copy on every index."""

    robot: RobotModel
    njoints: int
    names: list
    parents: list
    source: list  # per joint id: (wire column, mult, offset); (-1, 1, 0) for the root
    kinds: list  # per joint id: (kind, axis index, unit axis) or (None, -1, type name)
    placements: list
    masses: list  # per joint id: (mass, lever)
    frames: dict

    def frame(self, robot: RobotModel, name: str) -> tuple[int, pin.SE3]:
        if name not in self.frames:
            robot.frame_id(name)  # raises the clear error
        return self.frames[name]


def _statics(robot: RobotModel) -> _Statics:
    """The model's joint tables for the reduced kinematics, derived once per robot model."""
    return robot.derived("evaluator_statics", lambda: _build_statics(robot))


def _build_statics(robot: RobotModel) -> _Statics:
    model = robot.pin_model
    src_of_pinq = {int(p): (int(s), float(m), float(o)) for p, s, m, o in zip(robot.pin_q_index, robot.q_source, robot.q_mult, robot.q_offset)}
    idx_qs, parents, joints, inertias = list(model.idx_qs), list(model.parents), list(model.joints), list(model.inertias)
    kinds, source = [], []
    for jid, jm in enumerate(joints):
        short = jm.shortname()
        if short in _KINDS:
            kind, ax = _KINDS[short]
            axis = np.eye(3)[ax] if ax >= 0 else np.array(jm.extract().axis, dtype=float)
            kinds.append((kind, ax, axis / np.linalg.norm(axis)))
        else:
            kinds.append((None, -1, short))
        source.append(src_of_pinq.get(int(idx_qs[jid]), (-1, 1.0, 0.0)) if jid >= 2 else (-1, 1.0, 0.0))
    frames = {f.name: (int(f.parentJoint), f.placement.copy()) for f in model.frames}
    st = _Statics(
        robot=robot, njoints=model.njoints, names=list(model.names), parents=[int(p) for p in parents], source=source, kinds=kinds,
        placements=[p.copy() for p in model.jointPlacements],
        masses=[(float(i.mass), np.array(i.lever)) for i in inertias], frames=frames,
    )
    return st



class StateEvaluator:
    """System CoM (paper eq. 1), margin, stability and object pose of robot states in one stance.

    Shared by the planner's motion search and the stability survey. A batch may
    vary any joints; the evaluator finds which columns vary (or takes them as
    ``active``) and evaluates through a cached :class:`ReducedKinematics`.
    Leg joints are assumed to be those of the stance (they are never planned).
    """

    def __init__(self, robot: RobotModel, stance: Stance, threshold_m: float, object_mass: float, com_local: np.ndarray):
        if not np.isfinite(threshold_m) or threshold_m < 0:
            raise ValueError(f"threshold_m must be finite and >= 0, got {threshold_m}")
        if not np.isfinite(object_mass) or object_mass < 0:
            raise ValueError(f"object_mass must be finite and >= 0 (kg), got {object_mass}")
        com_local = np.asarray(com_local, dtype=float)
        if com_local.shape != (3,) or not np.all(np.isfinite(com_local)):
            raise ValueError(f"com_local must be 3 finite numbers (m), got {com_local}")
        self.robot = robot
        self.stance = stance
        self.threshold_m = float(threshold_m)
        self.object_mass = float(object_mass)
        self.com_local = com_local
        self.base_pose = np.asarray(stance.base_pose, dtype=float)
        self.polygon = stance.polygon
        self.robot_mass = float(robot.total_mass)
        self.tcp_frames = {side: robot.spec.arms[side].tcp for side in robot.spec.arms}
        self._cache: OrderedDict[tuple, ReducedKinematics] = OrderedDict()
        self._data = robot.create_data()
        self._tcp_fid = {side: robot.frame_id(f) for side, f in self.tcp_frames.items()}

    def with_threshold(self, threshold_m: float) -> "StateEvaluator":
        """The same evaluator with another threshold (shares nothing mutable that matters)."""
        return StateEvaluator(self.robot, self.stance, threshold_m, self.object_mass, self.com_local)

    def kinematics(self, q_ref: np.ndarray, active: Sequence[int]) -> ReducedKinematics:
        """The cached reduced tree for these active columns and the fixed values of ``q_ref``."""
        act = tuple(sorted(set(int(a) for a in active)))
        fixed = np.ones(self.robot.nq, dtype=bool)
        fixed[list(act)] = False
        key = (act, np.asarray(q_ref, dtype=float)[fixed].tobytes())
        rk = self._cache.get(key)
        if rk is None:
            rk = ReducedKinematics(self.robot, self.base_pose, q_ref, act, frames=tuple(self.tcp_frames.values()), data=self._data)
            self._cache[key] = rk
            if len(self._cache) > REDUCED_CACHE_SIZE:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return rk

    def object_poses(self, tcp_R: np.ndarray, tcp_p: np.ndarray, hold: HoldSpec) -> np.ndarray:
        """World object poses (N, 4, 4) from world TCP poses of the holding hand."""
        n = tcp_p.shape[0]
        T_tcp_obj = hold.T_tcp_obj
        out = np.zeros((n, 4, 4))
        out[:, :3, :3] = tcp_R @ T_tcp_obj[:3, :3]
        out[:, :3, 3] = tcp_p + tcp_R @ T_tcp_obj[:3, 3]
        out[:, 3, 3] = 1.0
        return out

    def with_object(self, robot_com: np.ndarray, object_pose: np.ndarray | None, threshold_m: float | None = None) -> StateBatch:
        """States from the robot's CoM (N, 3) and the object's world poses (N, 4, 4), or None when nothing is held:
        the system CoM (eq. 1), its margin and whether it is stable."""
        if object_pose is not None and self.object_mass > 0.0:
            obj_com = object_pose[:, :3, :3] @ self.com_local + object_pose[:, :3, 3]
            com = system_com(robot_com, self.robot_mass, obj_com, self.object_mass)
        else:
            com = robot_com
        margin = self.polygon.margin(com[:, :2])
        thr = self.threshold_m if threshold_m is None else threshold_m
        return StateBatch(robot_com=robot_com, com=com, margin=margin, stable=margin >= thr, object_pose=object_pose)

    def evaluate(
        self,
        Q: np.ndarray,
        hold: HoldSpec | None = None,
        active: Sequence[int] | None = None,
        threshold_m: float | None = None,
    ) -> StateBatch:
        """Evaluate a batch of full wire configurations Q (N, n).

        ``active`` names the columns that may vary (fastest when given, e.g.
        waist + arm); otherwise the columns that differ from the first row are used.
        Columns outside ``active`` must equal the first row's values.
        """
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        if Q.ndim != 2 or Q.shape[1] != self.robot.nq:
            raise ValueError(f"Q must have shape (N, {self.robot.nq}), got {Q.shape}")
        n = Q.shape[0]
        if n == 0:
            empty = np.zeros((0, 3))
            return StateBatch(empty, empty, np.zeros(0), np.zeros(0, bool), None if hold is None else np.zeros((0, 4, 4)))
        if n <= SMALL_BATCH:
            return self._evaluate_small(Q, hold, threshold_m)
        if active is None:
            active = np.flatnonzero(np.any(Q != Q[0], axis=0))
        else:
            fixed = np.ones(self.robot.nq, dtype=bool)
            fixed[np.asarray(active, dtype=int)] = False
            varying = np.flatnonzero(fixed & np.any(Q != Q[0], axis=0))
            if varying.size:
                names = ", ".join(self.robot.joint_names[i] for i in varying[:5])
                raise ValueError(f"joints outside 'active' vary within the batch: {names}")
        rk = self.kinematics(Q[0], active)
        if hold is None:
            return self.with_object(rk.com(Q), None, threshold_m)
        tcp = self.tcp_frames[hold.tcp_side]
        robot_com, frames = rk.com_and_frames(Q, (tcp,))
        R, p = frames[tcp]
        return self.with_object(robot_com, self.object_poses(R, p, hold), threshold_m)

    def _evaluate_small(self, Q: np.ndarray, hold: HoldSpec | None, threshold_m: float | None) -> StateBatch:
        """A few states through pinocchio one by one: cheaper than setting up a reduced tree."""
        model, data = self.robot.pin_model, self._data
        n = Q.shape[0]
        robot_com = np.empty((n, 3))
        poses = None if hold is None else np.empty((n, 4, 4))
        fid = None if hold is None else self._tcp_fid[hold.tcp_side]
        for i in range(n):
            robot_com[i] = pin.centerOfMass(model, data, self.robot.to_pin_q(self.base_pose, Q[i]), False)
            if poses is not None:
                poses[i] = pin.updateFramePlacement(model, data, fid).homogeneous
        if poses is not None:
            poses = poses @ hold.T_tcp_obj
        return self.with_object(robot_com, poses, threshold_m)

    def evaluate_one(self, q: np.ndarray, hold: HoldSpec | None = None, threshold_m: float | None = None) -> StateOne:
        """One state through pinocchio directly (no batch set-up cost)."""
        q = np.asarray(q, dtype=float)
        model, data = self.robot.pin_model, self._data
        robot_com = np.array(pin.centerOfMass(model, data, self.robot.to_pin_q(self.base_pose, q), False))
        object_pose = None
        com = robot_com
        if hold is not None:
            M = pin.updateFramePlacement(model, data, self._tcp_fid[hold.tcp_side])
            object_pose = M.homogeneous @ hold.T_tcp_obj
            if self.object_mass > 0.0:
                obj_com = object_pose[:3, :3] @ self.com_local + object_pose[:3, 3]
                com = system_com(robot_com, self.robot_mass, obj_com, self.object_mass)
        margin = self.polygon.margin_one(float(com[0]), float(com[1]))
        thr = self.threshold_m if threshold_m is None else threshold_m
        return StateOne(robot_com=robot_com, com=com, margin=margin, stable=margin >= thr, object_pose=object_pose)

    def tcp_pose(self, q: np.ndarray, side: Literal["left", "right"]) -> np.ndarray:
        """World pose (4, 4) of one hand's TCP, one state."""
        model, data = self.robot.pin_model, self._data
        pin.forwardKinematics(model, data, self.robot.to_pin_q(self.base_pose, np.asarray(q, dtype=float)))
        return pin.updateFramePlacement(model, data, self._tcp_fid[side]).homogeneous.copy()
