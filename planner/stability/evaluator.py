"""Stability of robot states with a held object: system CoM, margin and object pose, in batches.

The planner's T-RRT and the stability survey evaluate tens of thousands of
configurations of one robot in one stance; the robot's CoM comes from the batched
kinematics of the joints a batch moves (:class:`planner.kinematics.reduced.ReducedKinematics`).

The system CoM is the paper's equation 1 (:func:`planner.stability.com.system_com`)
and the margin is the signed distance of its ground projection to the support
polygon edge (:meth:`planner.stability.support_polygon.SupportPolygon.margin`).

Grasp convention: a :class:`HoldSpec` carries ``T_obj_tcp``, the pose of the
holding hand's TCP frame expressed in the object frame (a grasp as stored per
object). The object's world pose is then ``T_world_tcp @ inv(T_obj_tcp)``.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, Sequence

import numpy as np
import pinocchio as pin

from planner.kinematics.reduced import ReducedKinematics
from planner.robot.model import RobotModel
from planner.stability.com import object_com_world, system_com
from planner.stability.robot_com import robot_com_pin
from planner.stability.stances import Stance
from planner.transforms import inverse

HoldSide = Literal["left", "right", "both"]
#: How many reduced kinematic trees one evaluator keeps (one per active joint set / fixed posture).
REDUCED_CACHE_SIZE = 16
#: Batches up to this size go through pinocchio state by state (no reduced-tree set-up).
SMALL_BATCH = 16
_I3 = np.eye(3)


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
        # giver posture (hundreds per dual-arm survey), where np.allclose and det would dominate.
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

    @cached_property
    def T_tcp_obj(self) -> np.ndarray:
        """The object frame expressed in the holding TCP frame (computed once: the survey's checks ask for it
        every batch; read-only, as it is shared)."""
        T = inverse(self.T_obj_tcp)
        T.setflags(write=False)
        return T

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
            # Built at a canonical value of the active joints (zero), so that the tree, and with it
            # every last bit of the CoMs it computes, depends on the key alone: not on which state of
            # a batch happened to build it first (the evaluation order differs between a serial run
            # and one that shares its motions with a forked helper).
            q_canon = np.array(q_ref, dtype=float)
            q_canon[list(act)] = 0.0
            rk = ReducedKinematics(self.robot, self.base_pose, q_canon, act, frames=tuple(self.tcp_frames.values()), data=self._data)
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
            com = system_com(robot_com, self.robot_mass, object_com_world(object_pose, self.com_local), self.object_mass)
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
            robot_com[i] = robot_com_pin(self.robot, data, self.robot.to_pin_q(self.base_pose, Q[i]))
            if poses is not None:
                poses[i] = pin.updateFramePlacement(model, data, fid).homogeneous
        if poses is not None:
            poses = poses @ hold.T_tcp_obj
        return self.with_object(robot_com, poses, threshold_m)

    def evaluate_one(self, q: np.ndarray, hold: HoldSpec | None = None, threshold_m: float | None = None) -> StateOne:
        """One state through pinocchio directly (no batch set-up cost)."""
        q = np.asarray(q, dtype=float)
        model, data = self.robot.pin_model, self._data
        robot_com = np.array(robot_com_pin(self.robot, data, self.robot.to_pin_q(self.base_pose, q)))
        object_pose = None
        com = robot_com
        if hold is not None:
            M = pin.updateFramePlacement(model, data, self._tcp_fid[hold.tcp_side])
            object_pose = M.homogeneous @ hold.T_tcp_obj
            if self.object_mass > 0.0:
                com = system_com(robot_com, self.robot_mass, object_com_world(object_pose, self.com_local), self.object_mass)
        margin = self.polygon.margin_one(float(com[0]), float(com[1]))
        thr = self.threshold_m if threshold_m is None else threshold_m
        return StateOne(robot_com=robot_com, com=com, margin=margin, stable=margin >= thr, object_pose=object_pose)

    def tcp_pose(self, q: np.ndarray, side: Literal["left", "right"]) -> np.ndarray:
        """World pose (4, 4) of one hand's TCP, one state."""
        model, data = self.robot.pin_model, self._data
        pin.forwardKinematics(model, data, self.robot.to_pin_q(self.base_pose, np.asarray(q, dtype=float)))
        return pin.updateFramePlacement(model, data, self._tcp_fid[side]).homogeneous.copy()
