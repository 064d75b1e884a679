"""Compile the planner's kernels (or load them from numba's cache) before work that has a deadline.

The compiled inner loops (:mod:`planner.compiled.tree_kernels`, :mod:`planner.compiled.box_kernels`,
:mod:`planner.compiled.ik_kernels`) are compiled on their first call: once per machine, ~10 s on two cores,
after which every process loads the machine code from the cache in a fraction of a second. A job
with a time limit, a test with a timeout or a service worker should not pay that inside its budget:
:func:`warm_up` makes every kernel ready, through the same calls planning makes, so the argument
types (and so the compiled variants) are the ones planning uses.
"""

from __future__ import annotations

import time

import numpy as np


def warm_up(robot_name: str = "hrp5p") -> float:
    """Run every kernel once on a small real problem (a stance, a table, a few configurations, one IK
    target); returns the seconds it took."""
    from planner.compiled.box_kernels import hypotheses_hit, obb_penetration
    from planner.motion.ik import IkSettings, IkSolver
    from planner.robot.model import load_robot
    from planner.scene.bodies import EnvBox
    from planner.scene.collision import CollisionWorld
    from planner.stability.evaluator import HoldSpec, StateEvaluator
    from planner.stability.stances import solve_stance

    t0 = time.perf_counter()
    robot = load_robot(robot_name)
    stance = solve_stance(robot, "upright")
    table = np.eye(4)
    table[:3, 3] = [0.6, 0.0, 0.35]
    world = CollisionWorld(robot, [EnvBox("table", table, (0.5, 1.0, 0.7))])
    ik = IkSolver(robot, stance, IkSettings(restarts=0))
    side = next(iter(robot.spec.arms))
    arm = ik.active_indices([side])
    Q = np.repeat(stance.q[None], 20, axis=0)
    Q[:, arm] += np.linspace(-0.1, 0.1, len(Q))[:, None]
    world.check_batch(stance.base_pose, Q)  # forward walk, body boxes, screen (a batch)
    world.check_batch(stance.base_pose, Q[:1])  # and one state
    box = (np.eye(3)[None], np.zeros((1, 3)), np.full((1, 3), 0.1))
    obb_penetration(*box, *box)  # the SAT on its own
    hypotheses_hit(box[0][None], box[1][None], box[2], box[0][None], box[1][None], box[2], [True], [True], 0.0)  # hand filters
    evaluator = StateEvaluator(robot, stance, 0.0, 1.0, np.zeros(3))
    evaluator.evaluate(Q, HoldSpec(side, np.eye(4)), active=arm)  # reduced walk, CoM sum
    target = ik.tcp_pose(Q[-1], side)
    ik.solve_arm(side, target, stance.q, np.random.default_rng(0))  # the compiled descent
    return time.perf_counter() - t0
