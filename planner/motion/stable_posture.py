"""The nearest posture that keeps the hands where they are and the CoM margin at a threshold.

An IK solution reaches the hand's target but knows nothing of balance: holding a heavy object
far in front, the posture it finds often puts the system CoM closer to the polygon's edge than
the threshold, while another posture with the same hand pose (the waist leaning back, the arm
re-posed) keeps it. Before a key pose is given up for the CoM margin, the planner asks for that
posture: the joints of the waist and the arms move as little as possible (least squares from
the IK's posture) subject to

- each given hand's TCP staying at its pose (6 equations per hand),
- the system CoM (robot and held object) at least ``threshold_m`` inside every edge of the
  convex support polygon (one linear inequality per edge: the margin is the smallest of those
  distances), and
- the joint limits.

The held object's CoM does not move while the hands stay put, so only the robot's CoM varies;
planner/stability gives it and its Jacobian (pinocchio), and SciPy's SLSQP solves the small problem (an arm and
the waist; a refusal runs to the iteration cap; ``benchmarks/bench_stable_posture.py`` prints the times).
Leg joints are not moved: they hold the stance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import pinocchio as pin
from scipy.optimize import minimize

from planner.robot.model import RobotModel
from planner.stability.com import system_com_xy_fixed_object
from planner.stability.robot_com import robot_com_jacobian
from planner.stability.support_polygon import SupportPolygon

#: SLSQP iterations at most. The postures found converge in far fewer; one with none runs to the cap, so the
#: cap sets what a refusal costs: low enough to make refusals cheap, high enough to lose no posture found
#: (``benchmarks/bench_stable_posture.py`` prints the times).
MAX_ITERATIONS = 25
#: How close the hands must stay to their poses for the posture to count (m, rad).
HAND_POS_TOL_M = 1e-4
HAND_ROT_TOL_RAD = 1e-3


@dataclass(frozen=True)
class PostureProblem:
    """What stays fixed while the posture moves: the stance, the polygon, the held mass."""

    robot: RobotModel
    base_pose: np.ndarray
    polygon: SupportPolygon
    #: the held object's mass (kg) and its CoM in the world (m), fixed while the hands hold still
    object_mass_kg: float = 0.0
    object_com_world: np.ndarray | None = None
    #: pinocchio scratch for the solve (one per caller; made per solve when None)
    data: pin.Data | None = None


def stable_posture(problem: PostureProblem, q0: np.ndarray, columns: Sequence[int], hands: Mapping[str, np.ndarray],
                   threshold_m: float) -> np.ndarray | None:
    """The posture nearest ``q0`` (moving only ``columns``) with every TCP frame of ``hands`` (frame name ->
    world pose (4, 4)) where it is asked to be and the system CoM at least ``threshold_m`` inside the
    polygon; None when the solver finds none within the limits."""
    robot, model = problem.robot, problem.robot.pin_model
    data = problem.data if problem.data is not None else robot.create_data()
    cols = np.asarray(columns, dtype=int)
    vcols = np.array([model.idx_vs[model.getJointId(robot.joint_names[i])] for i in cols])
    fids = [robot.frame_id(f) for f in hands]
    targets = [pin.SE3(T[:3, :3], T[:3, 3]) for T in hands.values()]
    m_r, m_o = float(robot.total_mass), float(problem.object_mass_kg)
    polygon = problem.polygon
    x0 = q0[cols].astype(float)
    memo: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}

    def at(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """System CoM (xy), its Jacobian, the hands' errors (6 per hand) and their Jacobians at ``x``."""
        key = x.tobytes()
        if key not in memo:
            q = q0.copy()
            q[cols] = x
            qp = robot.to_pin_q(problem.base_pose, q)
            com, J_com = robot_com_jacobian(robot, data, qp)  # one forward pass for the CoM and the hands
            pin.updateFramePlacements(model, data)
            errs, jacs = [], []
            for fid, target in zip(fids, targets):
                errs.append(pin.log6(data.oMf[fid].actInv(target)).vector)
                jacs.append(pin.getFrameJacobian(model, data, fid, pin.LOCAL)[:, vcols])
            system, J_system = system_com_xy_fixed_object(com, J_com[:2, vcols], m_r, problem.object_com_world, m_o)
            memo.clear()
            memo[key] = (system, J_system, np.concatenate(errs), np.vstack(jacs))
        return memo[key]

    constraints = [
        # log6 of (current^-1 target) is the twist that takes the TCP to its target; d(error)/dq ~ -J.
        {"type": "eq", "fun": lambda x: at(x)[2], "jac": lambda x: -at(x)[3]},
        {"type": "ineq", "fun": lambda x: polygon.edge_distances(at(x)[0]) - threshold_m, "jac": lambda x: polygon.normals @ at(x)[1]},
    ]
    res = minimize(lambda x: 0.5 * float(np.sum((x - x0) ** 2)), x0, jac=lambda x: x - x0, method="SLSQP",
                   bounds=list(zip(robot.lower[cols], robot.upper[cols])), constraints=constraints,
                   options={"maxiter": MAX_ITERATIONS, "ftol": 1e-10})
    x = np.clip(res.x, robot.lower[cols], robot.upper[cols])
    system, _, err, _ = at(x)
    err = err.reshape(-1, 6)
    if (np.linalg.norm(err[:, :3], axis=1).max() > HAND_POS_TOL_M or np.linalg.norm(err[:, 3:], axis=1).max() > HAND_ROT_TOL_RAD
            or polygon.edge_distances(system).min() < threshold_m - 1e-6):
        return None
    q = q0.copy()
    q[cols] = x
    return q
