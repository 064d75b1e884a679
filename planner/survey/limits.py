"""Effort and grip limits in the stability survey: a pose over a limit counts as unstable.

The survey's exploration classifies every counted pose with a :class:`StateEvaluator`;
:func:`limited` wraps that evaluator so that ``stable`` also requires the static joint torques
and the grip to be within the robot's limits (:mod:`planner.stability.effort`), and
:func:`over_limits` counts the counted poses that are over a limit (the row's ``over_limits``).
With the limits off (``PlannerSettings.limits``) both leave the survey as the paper ran it.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import numpy as np

from planner.errors import Canceled
from planner.kinematics.batch import select_states
from planner.stability.effort import EffortEvaluator
from planner.stability.evaluator import HoldSpec, StateBatch, StateEvaluator
from planner.termination import never
from planner.transforms import quat_to_matrix


class LimitedEvaluator:
    """A :class:`StateEvaluator` whose ``stable`` also needs the effort and grip limits; the rest delegates."""

    def __init__(self, evaluator: StateEvaluator, limits: EffortEvaluator):
        self._evaluator = evaluator
        self.limits = limits

    def __getattr__(self, name: str) -> Any:
        return getattr(self._evaluator, name)

    @property
    def margin_evaluator(self) -> StateEvaluator:
        """The wrapped evaluator (the margin alone)."""
        return self._evaluator

    def evaluate(self, Q: np.ndarray, hold: HoldSpec | None = None, active: Sequence[int] | None = None,
                 threshold_m: float | None = None) -> StateBatch:
        batch = self._evaluator.evaluate(Q, hold, active=active, threshold_m=threshold_m)
        if len(batch) == 0 or not batch.stable.any():
            return batch
        stable = stable_within_limits(self.limits, np.atleast_2d(Q), batch, "none" if hold is None else hold.side)
        return dataclasses.replace(batch, stable=stable)


def stable_within_limits(limits: EffortEvaluator, Q: np.ndarray, batch: StateBatch, side: str,
                         frames: tuple[list, list] | None = None) -> np.ndarray:
    """``batch.stable`` with the effort and grip limits: only the poses stable by the margin can be turned unstable
    by a limit, so only they are checked. ``frames``: the batch's forward kinematics (all of Q's states), when the
    caller has them."""
    stable = batch.stable.copy()
    if not stable.any():
        return stable
    idx = np.flatnonzero(stable)
    poses = None if batch.object_pose is None else np.asarray(batch.object_pose)[idx]
    kw = {} if frames is None else {"frames": select_states(*frames, idx)}
    stable[idx] = limits.evaluate(Q[idx], side, object_pose=poses, **kw).ok
    return stable


def limited(task: Any, evaluator: StateEvaluator) -> StateEvaluator | LimitedEvaluator:
    """The survey's evaluator for ``task``: with the limits when the task checks them."""
    return evaluator if task.limits is None else LimitedEvaluator(evaluator, task.limits)


#: states per batch of :func:`over_limits`: a few tens of milliseconds between two polls of the cancel
OVER_LIMITS_BATCH = 4096


def over_limits(limits: EffortEvaluator, q: np.ndarray, holding: np.ndarray, object_pose7: np.ndarray,
                should_stop: Callable[[], bool] = never) -> int:
    """How many counted poses (q (N, n), holding (N,), object poses (N, 7)) are over an effort or grip limit.

    A long seed counts hundreds of thousands of poses (a second or more of torques): they go in batches of
    :data:`OVER_LIMITS_BATCH`, ``should_stop`` polled before each (:class:`~planner.errors.Canceled` when it asks)."""
    if len(q) == 0:
        return 0
    T = np.zeros((len(q), 4, 4))
    T[:, :3, :3] = quat_to_matrix(np.asarray(object_pose7)[:, 3:])
    T[:, :3, 3] = np.asarray(object_pose7)[:, :3]
    T[:, 3, 3] = 1.0
    count = 0
    holding = np.asarray(holding).astype(str)
    for label in np.unique(holding):
        idx = np.flatnonzero(holding == label)
        for start in range(0, len(idx), OVER_LIMITS_BATCH):
            if should_stop():
                raise Canceled()
            batch = idx[start:start + OVER_LIMITS_BATCH]
            count += int((~limits.evaluate(q[batch], label, object_pose=T[batch]).ok).sum())
    return count
