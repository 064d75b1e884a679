"""Assemble timed motion pieces into the plan file's trajectory (docs/contract.md section 3).

The regrasp search returns a sequence of motion pieces (joint-space paths with
what is held during each). This module times every piece from rest to rest,
concatenates them at the uniform period, and fills each point with the object
pose, the system CoM (paper eq. 1), the margin and the cart-table ZMP.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from planner.motion.timing import zmp_cart_table
from planner.stability.effort import EffortEvaluator
from planner.stability.evaluator import HoldSpec, StateEvaluator
from planner.transforms import matrices_to_pose7

Kind = Literal["transit", "transfer", "handover", "approach", "retreat"]


@dataclass
class MotionPiece:
    """One stretch of the plan: a joint path and what the hands hold along it.

    ``hold`` says how the object follows the robot while held (for the timing's checks);
    where the object is, held or resting, :func:`assemble` tracks through the plan.
    """

    kind: Kind
    hand: Literal["left", "right", "both", "none"]
    waypoints: np.ndarray
    holding: Literal["none", "left", "right", "both"]
    hold: HoldSpec | None
    #: the validated joint path (waypoints joined by straight segments) once ``waypoints`` holds its timed samples
    path: np.ndarray | None = None

    def joint_path(self) -> np.ndarray:
        """The piece's joint path: its validated path once timed, its waypoints before."""
        return np.asarray(self.path if self.path is not None else self.waypoints, dtype=float)


@dataclass
class TimedTrajectory:
    t: np.ndarray
    Q: np.ndarray
    holding: list[str]
    object_pose: np.ndarray  # (M, 4, 4)
    com: np.ndarray  # (M, 3)
    margin: np.ndarray  # (M,)
    zmp: np.ndarray  # (M, 2)
    segments: list[dict]
    #: (M,) max over joints of |static torque| / effort limit (:func:`effort_ratios`), once computed
    effort_ratio: np.ndarray | None = None


def _sides(holding: str) -> tuple[str, ...]:
    return {"none": (), "left": ("left",), "right": ("right",), "both": ("left", "right")}[holding]


def object_states(pieces: list[MotionPiece], evaluator: StateEvaluator, start_object_pose: np.ndarray):
    """Per non-empty piece: (piece, holding, the HoldSpec of the grasp as actually held or None, the
    object's world pose at the piece's start while it rests).

    The object's state is tracked through the plan, not taken from the pieces: when a hand closes on
    the object, its grasp is measured from where the object really is and where the TCP really is;
    when the last hand lets go, the object stays exactly where it was released."""
    current = np.asarray(start_object_pose, dtype=float)
    grasp: dict[str, np.ndarray] = {}  # side -> T_obj_tcp as actually held
    holding = "none"
    for piece in pieces:
        Q = np.asarray(piece.waypoints, dtype=float)
        if len(Q) == 0:
            continue
        if piece.holding != holding:
            if holding != "none":  # where the object is at this instant, from a hand that held it
                side = "left" if holding == "both" else holding
                current = evaluator.tcp_pose(Q[0], side) @ np.linalg.inv(grasp[side])
            for side in _sides(piece.holding):
                if side not in grasp:
                    grasp[side] = np.linalg.inv(current) @ evaluator.tcp_pose(Q[0], side)
            grasp = {side: T for side, T in grasp.items() if side in _sides(piece.holding)}
            holding = piece.holding
        if holding == "none":
            hold = None
        else:
            side = "left" if holding == "both" else holding
            hold = HoldSpec(holding, grasp[side])
        yield piece, holding, hold, current


def assemble(pieces: list[MotionPiece], evaluator: StateEvaluator, dt: float, start_object_pose: np.ndarray) -> TimedTrajectory:
    """Concatenate timed pieces (each from rest to rest, already sampled at ``dt``).

    The object's state is tracked through the plan, not taken from the pieces: when a
    hand closes on the object, its grasp is measured from where the object really is
    and where the TCP really is; when the last hand lets go, the object stays exactly
    where it was released. So the object never jumps, even though IK reaches key
    poses only to a tolerance.
    """
    Qs: list[np.ndarray] = []
    holds: list[str] = []
    poses: list[np.ndarray] = []
    coms: list[np.ndarray] = []
    segments: list[dict] = []
    count = 0
    for piece, holding, hold, current in object_states(pieces, evaluator, start_object_pose):
        Q = np.asarray(piece.waypoints, dtype=float)
        batch = evaluator.evaluate(Q, hold, threshold_m=0.0)
        pose = np.repeat(current[None], len(Q), axis=0) if hold is None else batch.object_pose
        if count > 0:
            # The previous piece's last sample and this piece's first are the same rest state;
            # keep this piece's copy, since "holding" applies from a point onwards.
            Qs[-1], poses[-1], coms[-1] = Qs[-1][:-1], poses[-1][:-1], coms[-1][:-1]
            holds.pop()
            count -= 1
        first = count
        Qs.append(Q)
        holds += [holding] * len(Q)
        poses.append(pose)
        coms.append(batch.com)
        count += len(Q)
        segments.append({"kind": piece.kind, "hand": piece.hand, "first": first, "last": count - 1})
    Q = np.vstack(Qs)
    com = np.vstack(coms)
    t = np.arange(len(Q)) * dt
    return TimedTrajectory(
        t=t, Q=Q, holding=holds, object_pose=np.concatenate(poses), com=com,
        margin=evaluator.polygon.margin(com[:, :2]), zmp=zmp_cart_table(com, dt, holds), segments=segments,
    )


def effort_ratios(traj: TimedTrajectory, limits: EffortEvaluator) -> np.ndarray:
    """Each point's ``effort_ratio``: static torques with the object where the plan has it, per run of
    points holding the same way."""
    out = np.empty(len(traj.Q))
    holding = np.array(traj.holding)
    starts = np.flatnonzero(np.r_[True, holding[1:] != holding[:-1]])
    for a, b in zip(starts, [*starts[1:], len(holding)]):
        out[a:b] = limits.evaluate(traj.Q[a:b], holding[a], object_pose=traj.object_pose[a:b]).effort_ratio
    return out


def trajectory_points(traj: TimedTrajectory) -> list[dict]:
    """The plan's ``trajectory`` entries, floats at full precision (arrays converted whole: a plan
    has thousands of points, and per-point conversions cost ~0.4 s on a 50 s plan)."""
    poses = matrices_to_pose7(traj.object_pose).tolist()
    points = [
        {"t": t, "q": q, "holding": holding, "object_pose": pose, "com": com, "margin_m": margin, "zmp": zmp}
        for t, q, holding, pose, com, margin, zmp in zip(
            traj.t.tolist(), traj.Q.tolist(), traj.holding, poses, traj.com.tolist(), traj.margin.tolist(), traj.zmp.tolist())
    ]
    if traj.effort_ratio is not None:
        for point, ratio in zip(points, traj.effort_ratio.tolist()):
            point["effort_ratio"] = ratio
    return points
