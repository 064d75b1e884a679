"""The robot's centre of mass: the one place in the planner that computes it.

Two paths behind the same quantity, the CoM of the robot's links in the world:

- one state (or its Jacobian) through pinocchio, for the stance solver, the evaluator's small
  batches and the stable-posture solver;
- many states through the compiled kernel (:func:`planner.compiled.tree_kernels.weighted_sum`)
  over the link frames that the batched kinematics (:mod:`planner.kinematics`) computed: the mass
  of every link fixed to a frame, at its lever arm, plus the constant moment of the links that do
  not move.

The held object joins the robot's CoM in :mod:`planner.stability.com` (the paper's equation 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from planner.compiled.tree_kernels import weighted_sum
from planner.robot.model import RobotModel


@dataclass(frozen=True)
class BodyMasses:
    """The masses a batched kinematic tree carries: ``mass[k]`` at ``lever[k]`` in the frame of slot
    ``slots[k]``, plus ``base_moment`` (sum of mass x position of the links that never move) over the
    robot's ``total_mass``."""

    slots: np.ndarray
    mass: np.ndarray
    lever: np.ndarray
    base_moment: np.ndarray
    total_mass: float


def fold_masses(bodies: list[tuple[int, float, np.ndarray]], n_slots: int) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The composite body of each slot of a reduced tree: ``bodies`` lists (slot, mass, position) of the
    links, the position in the slot's frame, or in the world for slot -1 (fixed in the world). Returns
    each slot's mass (S,) and CoM lever in its frame (S, 3) (zero for a massless slot), and the total mass
    and moment (sum of mass x position) of the links fixed in the world."""
    mass = [0.0] * n_slots
    moment = [np.zeros(3) for _ in range(n_slots)]
    fixed_mass, fixed_moment = 0.0, np.zeros(3)
    for slot, m, c in bodies:
        if slot < 0:
            fixed_mass += m
            fixed_moment += m * c
        else:
            mass[slot] += m
            moment[slot] += m * c
    lever = np.array([moment[k] / mass[k] if mass[k] > 0 else np.zeros(3) for k in range(n_slots)], dtype=float).reshape(-1, 3)
    return np.array(mass, dtype=float), lever, fixed_mass, fixed_moment


def robot_com(robot: RobotModel, data: pin.Data, base_pose: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Robot CoM in the world (3,) for one wire configuration ``q`` with the free flyer at ``base_pose``."""
    return pin.centerOfMass(robot.pin_model, data, robot.to_pin_q(base_pose, q), False).copy()


def robot_com_pin(robot: RobotModel, data: pin.Data, q_pin: np.ndarray) -> np.ndarray:
    """Robot CoM (3,) of a pinocchio configuration; leaves the joint placements in ``data``."""
    return pin.centerOfMass(robot.pin_model, data, q_pin, False)


def robot_com_jacobian(robot: RobotModel, data: pin.Data, q_pin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Robot CoM (3,) and its Jacobian (3, nv) at a pinocchio configuration; also leaves the joint
    Jacobians and placements in ``data`` (one forward pass serves the frames too)."""
    model = robot.pin_model
    pin.computeJointJacobians(model, data, q_pin)
    J = pin.jacobianCenterOfMass(model, data, False)  # also sets data.com[0]
    return data.com[0], J


def robot_com_batch(R: np.ndarray, p: np.ndarray, masses: BodyMasses) -> np.ndarray:
    """Robot CoM in the world (N, 3) from the frames of a batched forward pass: rotations R (S, 3, 3, N)
    and positions p (S, 3, N) of the tree's slots (the compiled path)."""
    return weighted_sum(R, p, masses.slots, masses.mass, masses.lever, masses.base_moment, masses.total_mass)
