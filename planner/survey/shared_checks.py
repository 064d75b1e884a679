"""A survey leg's checks of a batch of poses from one forward-kinematics pass.

Each pose the survey's exploration steers to, and each point on an edge it checks, needs three
things of the robot's kinematics: the system CoM (the margin), the static torques and grip (the
effort limits, on the poses stable by the margin) and the bodies' poses (the collision check).
Done one after another, each computed the forward kinematics of the same states again: the CoM
through pinocchio or a reduced tree, the limits and the collision check through the batched
kinematics, each on its own. :class:`LegChecks` computes the batched forward kinematics once per
batch and derives all three from it: the robot's CoM and the holding hand's TCP (so the held
object's pose, shared by the CoM, the limits and the collision check) from the same frames the
limits and the collision check read.

Only the survey's counted exploration uses it (:mod:`planner.survey.counting`); a plan's checks
are those of :mod:`planner.motion.edge_checks` and :mod:`planner.regrasp.state_checker`, unchanged.
The batched kinematics agree with pinocchio to rounding (``tests/kinematics``); the survey's counts
with and without the shared pass are the same (``tests/survey/test_shared_checks.py``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.kinematics.batch import BatchKinematics, select_states
from planner.scene.collision import CollisionWorld
from planner.stability.effort import EffortEvaluator
from planner.stability.evaluator import HoldSpec, StateBatch, StateEvaluator
from planner.survey.limits import stable_within_limits


@dataclass(frozen=True)
class HeldCollisions:
    """A leg's collision check: the task's collision world at the stance, the object held by ``hold``.

    Called with configurations (N, n) it returns which are collision-free (the plain check);
    :meth:`on_frames` checks states whose forward kinematics and held-object poses the caller has."""

    world: CollisionWorld
    base_pose: np.ndarray
    hold: HoldSpec

    @property
    def held(self) -> list[tuple[str, np.ndarray]]:
        """What the collision world carries: the object in the holding hand."""
        return [(self.hold.tcp_side, self.hold.T_obj_tcp)]

    def __call__(self, Q: np.ndarray) -> np.ndarray:
        return ~self.world.check_batch(self.base_pose, Q, held=self.held).collides

    def on_frames(self, frames: tuple[list, list], object_pose: np.ndarray) -> np.ndarray:
        """Which states of a :meth:`BatchKinematics.forward` result (with their held object's world poses
        (N, 4, 4)) are collision-free."""
        return ~self.world.check_forward(*frames, held=self.held, held_object_poses=object_pose).collides


class LegChecks:
    """The margin, the effort limits and the collision check of a leg's poses, from one forward pass per batch."""

    def __init__(self, evaluator: StateEvaluator, limits: EffortEvaluator | None, collisions: HeldCollisions):
        self.evaluator = evaluator
        self.limits = limits
        self.collisions = collisions
        self.hold = collisions.hold
        self.kin: BatchKinematics = collisions.world.kin
        self.base_pose = np.asarray(collisions.base_pose, dtype=float)
        self.tcp_frame = evaluator.tcp_frames[self.hold.tcp_side]

    def _states(self, Q: np.ndarray) -> tuple[StateBatch, tuple[list, list]]:
        """The states' CoM, margin and held-object poses, and their forward kinematics."""
        frames = self.kin.forward(self.base_pose, Q)
        robot_com = self.kin.com_from(*frames)
        R, p = self.kin.frame(*frames, self.tcp_frame)
        return self.evaluator.with_object(robot_com, self.evaluator.object_poses(R, p, self.hold)), frames

    def _within_limits(self, Q: np.ndarray, batch: StateBatch, frames: tuple[list, list]) -> np.ndarray:
        """``stable`` with the effort and grip limits (checked on the states stable by the margin only)."""
        if self.limits is None:
            return batch.stable.copy()
        return stable_within_limits(self.limits, Q, batch, self.hold.side, frames)

    def judge(self, Q: np.ndarray) -> tuple[StateBatch, np.ndarray]:
        """Steered poses Q (N, n): their states (``stable`` with the limits) and which are collision-free (all of them
        are checked: a colliding pose is not counted)."""
        batch, frames = self._states(Q)
        stable = self._within_limits(Q, batch, frames)
        free = self.collisions.on_frames(frames, batch.object_pose)
        return dataclasses.replace(batch, stable=stable), free

    def valid(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Edge checks Q (N, n): stable (margin, then limits), then collision-free (only the stable ones); and the margins."""
        batch, frames = self._states(Q)
        ok = self._within_limits(Q, batch, frames)
        if ok.any():
            idx = np.flatnonzero(ok)
            ok[idx] = self.collisions.on_frames(select_states(*frames, idx), batch.object_pose[idx])
        return ok, batch.margin


def leg_checks(evaluator: Any, collision_free: Any, hold: HoldSpec | None) -> LegChecks | None:
    """The shared checks of a leg, when its collision check is a :class:`HeldCollisions` at the evaluator's stance
    (else None: the leg checks with the evaluator and its collision callable one after the other)."""
    if not isinstance(collision_free, HeldCollisions) or hold is None or collision_free.hold is not hold:
        return None
    margin_evaluator = getattr(evaluator, "margin_evaluator", evaluator)
    if not isinstance(margin_evaluator, StateEvaluator):
        return None
    if collision_free.world.robot is not margin_evaluator.robot or not np.array_equal(
            np.asarray(collision_free.base_pose, dtype=float), margin_evaluator.base_pose):
        return None
    return LegChecks(margin_evaluator, getattr(evaluator, "limits", None), collision_free)
