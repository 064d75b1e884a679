"""The system CoM along a joint path and its first two path derivatives: the terms the ZMP needs.

Along a path ``q(s)`` timed by ``s(t)``, the system CoM ``c(q(s))`` moves with
``c_dot = c'(s) s_dot`` and ``c_ddot = c'(s) s_ddot + c''(s) s_dot^2``, where
``c' = Dc[q']`` and ``c'' = D^2c[q', q'] + Dc[q'']``. The directional derivatives come from
central differences of the system CoM in joint space, through the one evaluator of the
planner (:class:`planner.stability.evaluator.StateEvaluator`: the robot's CoM plus the held
object by equation 1), so they are exactly as smooth as the CoM itself, whatever the path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.stability.evaluator import HoldSpec, StateEvaluator

#: Joint-space step (rad) of the central differences along a unit direction.
STEP_RAD = 1e-4


@dataclass(frozen=True)
class ComPathTerms:
    """At each path point: the system CoM ``com`` (N, 3), ``d1`` = dc/ds (N, 3), ``d2`` = d2c/ds2 (N, 3)."""

    com: np.ndarray
    d1: np.ndarray
    d2: np.ndarray


def com_path_terms(evaluator: StateEvaluator, Q: np.ndarray, dQ: np.ndarray, ddQ: np.ndarray,
                   hold: HoldSpec | None) -> ComPathTerms:
    """The system CoM and its path derivatives at the points ``Q`` (N, n) of a path whose derivatives
    with respect to the path parameter are ``dQ`` and ``ddQ`` (N, n)."""
    Q, dQ, ddQ = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (Q, dQ, ddQ))
    n = len(Q)
    h1 = STEP_RAD / np.maximum(np.abs(dQ).max(axis=1), 1e-12)[:, None]
    h2 = STEP_RAD / np.maximum(np.abs(ddQ).max(axis=1), 1e-12)[:, None]
    batch = np.vstack([Q, Q + h1 * dQ, Q - h1 * dQ, Q + h2 * ddQ, Q - h2 * ddQ])
    c = evaluator.evaluate(batch, hold, threshold_m=0.0).com
    c0, cp, cm, ap, am = (c[k * n:(k + 1) * n] for k in range(5))
    d1 = (cp - cm) / (2.0 * h1)
    second = (cp - 2.0 * c0 + cm) / (h1 * h1) + (ap - am) / (2.0 * h2)
    second[np.abs(ddQ).max(axis=1) == 0.0] = ((cp - 2.0 * c0 + cm) / (h1 * h1))[np.abs(ddQ).max(axis=1) == 0.0]
    return ComPathTerms(com=c0, d1=d1, d2=second)
