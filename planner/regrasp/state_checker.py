"""The regrasp task's state validity checker: whether robot states are valid, with their clearance.

Like OMPL's ``StateValidityChecker``, it answers validity and clearance; the clearance is the
CoM margin (the signed distance of the system CoM's ground projection to the support polygon's
edge). A state is valid when it is collision-free and, for the constrained planner
(threshold > 0), its margin reaches the planning threshold, and, unless the limits are off, its
static joint torques stay within the effort limits and the grip holds the object
(:mod:`planner.stability.effort`). It also names the first failing cause over a run of states
(com_margin, effort, grip, collision: cheapest first), the failure counts the planner reports.
"""

from __future__ import annotations

from collections import Counter
from typing import Callable

import numpy as np

from planner.kinematics.batch import select_states
from planner.regrasp.failure_cause import FailureCause
from planner.array_keys import array_key
from planner.regrasp.seed_free import SeedFreeResults
from planner.scene.collision import CollisionWorld
from planner.stability.effort import EffortEvaluator
from planner.stability.evaluator import HoldSpec, StateEvaluator


class StateChecker:
    """Validity and clearance of states of one task (its stance, evaluator and collision world).

    Counts the states it checks in ``counters`` (the task's, so that the plan reports them).
    """

    def __init__(self, evaluator: StateEvaluator, world: CollisionWorld, base_pose: np.ndarray, constrained: bool,
                 counters: Counter, limits: EffortEvaluator | None = None):
        self.evaluator = evaluator
        self.limits = limits
        self.world = world
        self.base_pose = base_pose
        self.constrained = constrained
        self.counters = counters
        #: seed-free results shared with searches of the same problem under other seeds (None: not shared)
        self.seed_free: SeedFreeResults | None = None

    def validity(self, hold: HoldSpec | None, free_object: np.ndarray | None, grasping: str | None = None,
                 active: np.ndarray | None = None) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """validity(Q) -> (valid, margin): collision-free and (if constrained) margin >= threshold."""
        held = [(hold.tcp_side, hold.T_obj_tcp)] if hold is not None else []

        def check(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            Q = np.atleast_2d(Q)
            batch = self.evaluator.evaluate(Q, hold, active=active)
            self.counters["com_states"] += len(Q)
            ok = batch.stable.copy() if self.constrained else np.ones(len(Q), dtype=bool)
            if ok.any():
                idx = np.flatnonzero(ok)
                Rs, ps = self.world.kin.forward(self.base_pose, Q[idx])  # one FK for the limits and the collisions
                if self.limits is not None:
                    within = self._limit_causes(Q[idx], hold, (Rs, ps)) == 0
                    ok[idx] = within
                    if not within.all():
                        idx = idx[within]
                        Rs, ps = select_states(Rs, ps, np.flatnonzero(within))
                if idx.size:
                    res = self.world.check_forward(Rs, ps, held=held, free_object_pose=None if held else free_object,
                                                   grasping=grasping)
                    self.counters["collision_states"] += len(idx)
                    ok[idx] = ~res.collides
            return ok, batch.margin

        return check

    def classify(self, Q: np.ndarray, hold: HoldSpec | None, free_object: np.ndarray | None,
                 grasping: str | None = None) -> tuple[FailureCause | None, float]:
        """The first failing cause over states Q (com_margin before collision), and the min margin."""
        causes, margins = self.classify_groups(np.atleast_2d(Q), 1, hold, free_object, grasping)
        return causes[0], float(margins[0])

    def classify_groups(self, Q: np.ndarray, groups: int, hold: HoldSpec | None, free_object: np.ndarray | None,
                        grasping: str | None = None) -> tuple[list[FailureCause | None], np.ndarray]:
        """:meth:`classify` for ``groups`` equal runs of consecutive states of Q at once: each run's first
        failing cause and min margin. ``free_object`` is one pose, or one per state (N, 4, 4); runs that
        fail on the margin are not checked for collision."""
        if self.seed_free is None:
            return self._classify_groups(Q, groups, hold, free_object, grasping)
        key = ("groups", groups, grasping, None if hold is None else hold.side,
               *array_key(Q, None if hold is None else hold.T_obj_tcp, free_object))
        return self.seed_free.checks(key, lambda: self._classify_groups(Q, groups, hold, free_object, grasping))

    def _classify_groups(self, Q: np.ndarray, groups: int, hold: HoldSpec | None, free_object: np.ndarray | None,
                         grasping: str | None) -> tuple[list[FailureCause | None], np.ndarray]:
        k = len(Q) // groups
        batch = self.evaluator.evaluate(Q, hold)
        self.counters["com_states"] += len(Q)
        margins = batch.margin.reshape(groups, k).min(axis=1)
        unstable = ~batch.stable.reshape(groups, k).all(axis=1) if self.constrained else np.zeros(groups, dtype=bool)
        causes: list[FailureCause | None] = [FailureCause.COM_MARGIN if u else None for u in unstable]
        groups_in = np.flatnonzero(~unstable)
        if not groups_in.size:
            return causes, margins
        rows_in = (groups_in[:, None] * k + np.arange(k)).ravel()
        frames = self.world.kin.forward(self.base_pose, Q[rows_in])  # one FK for the limits and the collisions
        check = groups_in
        if self.limits is not None:
            codes = self._limit_causes(Q[rows_in], hold, frames).reshape(-1, k)
            for g, row_codes in zip(groups_in, codes):
                bad = row_codes[row_codes > 0]
                if bad.size:  # the first failing state's cause
                    causes[g] = _LIMIT_CAUSE[int(bad[0])]
            within = ~(codes > 0).any(axis=1)
            check = groups_in[within]
            if not within.all():
                frames = select_states(*frames, np.flatnonzero(np.repeat(within, k)))
        if check.size:
            rows = (check[:, None] * k + np.arange(k)).ravel()
            held = [(hold.tcp_side, hold.T_obj_tcp)] if hold is not None else []
            if free_object is not None and np.ndim(free_object) == 3:
                free_object = free_object[rows]
            res = self.world.check_forward(*frames, held=held, free_object_pose=None if held else free_object,
                                           grasping=grasping)
            self.counters["collision_states"] += len(rows)
            for g in check[res.collides.reshape(-1, k).any(axis=1)]:
                causes[g] = FailureCause.COLLISION
        return causes, margins


    def _limit_causes(self, Q: np.ndarray, hold: HoldSpec | None, frames: tuple[list, list]) -> np.ndarray:
        """Per state 0 (within the limits), 1 (a joint over its effort limit) or 2 (the grip slips); ``frames``:
        the states' forward kinematics at the stance."""
        holding = "none" if hold is None else hold.side
        res = self.limits.evaluate(Q, holding, T_tcp_obj=None if hold is None else hold.T_tcp_obj, frames=frames)
        self.counters["limit_states"] += len(Q)
        return np.where(~res.effort_ok, 1, np.where(~res.grip_ok, 2, 0))


_LIMIT_CAUSE = {1: FailureCause.EFFORT, 2: FailureCause.GRIP}
