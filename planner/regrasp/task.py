"""A regrasp task: what one scenario asks, built once and shared by its hand configurations.

The robot in its stance, the object, grasps per hand (cached on disk), resting placements
(start, goal and a few intermediate spots), the collision world, the IK solvers and the stability
evaluator. Like pinocchio's ``Model``, a :class:`Task` is immutable once built; what a search learns
about it (node validations, probes, counters) lives in the search's own
:class:`planner.regrasp.search_data.SearchData` (``SearchData(task)``), like pinocchio's ``Data``.
"""

from __future__ import annotations

import time
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np
import pinocchio as pin

from planner.grasping.grasps import Grasp, plan_grasps
from planner.motion.ik import IkSolver
from planner.motion.interpolation import interpolate
from planner.regrasp.graph import HOP_KINDS, HandoverNode, PlacementNode
from planner.regrasp.settings import HANDS_INDEX, PlannerSettings, Side
from planner.regrasp.task_setup import choose_placements, ready_posture
from planner.robot.model import RobotModel, load_robot
from planner.scene.collision import CollisionWorld
from planner.scene.objects import ObjectModel, build_object
from planner.stability.effort import EffortEvaluator
from planner.stability.evaluator import StateEvaluator
from planner.stability.stances import Stance, solve_stance
from schemas.scenario import Scenario

SIDES: tuple[Side, Side] = ("left", "right")


class Task:
    """What one regrasp task is, built once, immutable after, and reused across hand configurations."""

    def __init__(self, scenario: Scenario, settings: PlannerSettings | None = None, *,
                 robot: RobotModel | None = None, threshold_m: float | None = None, seed: int | None = None):
        t0 = time.perf_counter()
        self.scenario = scenario
        self.settings = s = settings or PlannerSettings()
        self.robot = robot = robot or load_robot(scenario.robot)
        self.stance: Stance = solve_stance(robot, scenario.stance)
        self.threshold_m = scenario.threshold_m if threshold_m is None else threshold_m
        self.seed = scenario.seed if seed is None else seed
        self.constrained = self.threshold_m > 0.0
        self.obj: ObjectModel = build_object(scenario.object)
        planning_threshold = self.threshold_m + s.planning_buffer_m if self.constrained else 0.0
        self.evaluator = StateEvaluator(robot, self.stance, planning_threshold, self.obj.mass_kg, self.obj.com_local)
        t1 = time.perf_counter()
        grasp_sets = {side: plan_grasps(self.obj, robot, side, s.grasp) for side in SIDES}
        self.grasps: Mapping[Side, tuple[Grasp, ...]] = MappingProxyType(
            {side: tuple(gs.grasps)[: s.max_grasps] for side, gs in grasp_sets.items()})
        self.grasp_cache_hit: Mapping[Side, bool] = MappingProxyType({side: gs.from_cache for side, gs in grasp_sets.items()})
        grasps_s = time.perf_counter() - t1
        arms = robot.spec.arms.values()
        self.world = CollisionWorld.from_scenario(
            robot, scenario, self.obj, reference_postures=[(self.stance.base_pose, self.stance.q)],
            moving_joints=[*robot.spec.waist, *[j for a in arms for j in a.chain],
                           *[a.gripper.joint for a in arms if a.gripper is not None]],
        )
        #: static torques and grip, or None when the limits are switched off (``settings.limits``)
        self.limits: EffortEvaluator | None = (
            EffortEvaluator(robot, self.stance, self.obj.mass_kg, self.obj.com_local) if s.limits else None)
        self.ik = IkSolver(robot, self.stance, s.ik, kinematics=self.world.kin)
        # The arm-only attempt is a cheap first try (few restarts); the waist joins when it fails.
        self.ik_arm_only = IkSolver(robot, self.stance, s.ik.model_copy(update={"use_waist": False,
                                                                                "restarts": s.arm_only_restarts}),
                                    kinematics=self.world.kin)
        #: the columns of each hand's jaw joint: one, or none for a rigid hand (index arrays, so writing a
        #: jaw value into a state is a no-op for a rigid hand; :meth:`put_jaw`)
        self.jaw = MappingProxyType({side: np.array([robot.joint_index(g.joint)] if (g := robot.spec.arms[side].gripper)
                                                    else [], dtype=int) for side in SIDES})
        home = self.stance.q.copy()
        for side in SIDES:
            home[self.jaw[side]] = robot.upper[self.jaw[side]]  # jaws open at home
        home.flags.writeable = False
        self.home = home
        self.active = MappingProxyType({side: np.concatenate([robot.waist_indices(), robot.arm_indices(side)])
                                        for side in SIDES})
        self.arm_only = MappingProxyType({side: robot.arm_indices(side) for side in SIDES})
        self.shoulder, self.reach = self._shoulders_and_reach()
        self.ready = MappingProxyType({side: ready_posture(self, side) for side in SIDES})
        t2 = time.perf_counter()
        placements, self.start_id, self.goal_id = choose_placements(self)
        self.placements: tuple[np.ndarray, ...] = tuple(placements)
        self.setup_timings: Mapping[str, float] = MappingProxyType({
            "grasps_s": grasps_s, "placements_s": time.perf_counter() - t2, "setup_s": time.perf_counter() - t0})
        self._built = True

    def __setattr__(self, name: str, value: Any) -> None:
        if getattr(self, "_built", False):
            raise AttributeError(f"a Task is immutable once built (setting {name!r}); a search keeps what it "
                                 "learns in its SearchData")
        object.__setattr__(self, name, value)

    def _shoulders_and_reach(self) -> tuple[Mapping[Side, np.ndarray], Mapping[Side, float]]:
        """Each shoulder's position at home, and the longest TCP distance from it over the chain plus
        what the waist adds."""
        robot = self.robot
        data = robot.create_data()
        pin.framesForwardKinematics(robot.pin_model, data, robot.to_pin_q(self.stance.base_pose, self.home))
        shoulder, reach = {}, {}
        for side in SIDES:
            chain = robot.spec.arms[side].chain
            shoulder[side] = data.oMi[robot.pin_model.getJointId(chain[1])].translation.copy()
            tcp = data.oMf[robot.frame_id(robot.spec.arms[side].tcp)].translation
            links = [data.oMi[robot.pin_model.getJointId(j)].translation for j in chain[1:]] + [tcp]
            reach[side] = (float(sum(np.linalg.norm(b - a) for a, b in zip(links[:-1], links[1:])))
                           + self.settings.waist_reach_m)
        return MappingProxyType(shoulder), MappingProxyType(reach)

    def put_jaw(self, Q: np.ndarray, side: Side, values) -> None:
        """Write one jaw value per state into the rows of ``Q`` (nothing for a rigid hand)."""
        Q[:, self.jaw[side]] = np.asarray(values, dtype=float)[:, None]

    def handover_anchor(self) -> np.ndarray:
        """Where the handover positions are measured from: the stance's pelvis, moved by how far this robot's
        shoulders' midpoint sits from where the positions' reference robot has it (``HandoverSettings.shoulders_m``;
        rounded to a micrometre, so on the reference robot it is the pelvis exactly)."""
        pelvis = self.stance.base_pose[:3]
        mid = 0.5 * (self.shoulder["left"] + self.shoulder["right"])
        shift = np.round(mid - pelvis - np.asarray(self.settings.handover.shoulders_m, dtype=float), 6)
        return pelvis + shift

    def node_seed(self, node: PlacementNode | HandoverNode) -> list[int]:
        """The seed of a node's own generator: the task seed and the node's identity."""
        if isinstance(node, PlacementNode):
            return [self.seed, 0, node.placement, node.grasp, HANDS_INDEX[node.hand]]
        return [self.seed, 1, node.pose, node.giver_grasp, node.taker_grasp, HANDS_INDEX[node.giver]]

    def hop_seed(self, a: PlacementNode | HandoverNode | None, b: PlacementNode | HandoverNode | None, kind: str) -> list[int]:
        """The seed of the generator a motion between two key poses draws from (None: home), so a motion
        is the same whichever hop was planned before it, and in whichever process."""
        ends = [x for n in (a, b) for x in ([self.seed, 2] if n is None else self.node_seed(n))]
        return [*ends, HOP_KINDS.index(kind)]

    def tcp(self, q: np.ndarray, side: Side) -> np.ndarray:
        return self.evaluator.tcp_pose(q, side)

    def line(self, a: np.ndarray, b: np.ndarray, n: int | None = None) -> np.ndarray:
        """``n`` states from a to b, both included (default: the approach samples, more where a joint moves farther
        than ``line_check_rad`` between two of them, so a check of the line is as dense as the timed samples)."""
        if n is None:
            step = float(np.abs(np.asarray(b) - np.asarray(a)).max()) / self.settings.line_check_rad
            n = max(self.settings.approach_samples, int(np.ceil(step)) + 1)
        return interpolate(a, b, n)

    def estimated_margins(self, T_obj: np.ndarray) -> np.ndarray:
        """Quick guesses of a held state's margin, the home posture plus the object at each pose
        of T_obj (N, 4, 4) (eq. 1)."""
        robot_com = np.broadcast_to(self.stance.robot_com, (len(T_obj), 3))
        return self.evaluator.with_object(robot_com, T_obj).margin
