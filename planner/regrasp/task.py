"""A regrasp task: everything one scenario needs, built once and shared by its hand configurations.

The robot in its stance, the object, grasps per hand (cached on disk), resting placements
(start, goal and a few intermediate spots), handover poses (on first use), the collision world,
the IK solvers, the stability evaluator and the state checker, plus the caches of node
validations and probes that the hand configurations share.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Sequence

import numpy as np
import pinocchio as pin

from planner.grasping.grasps import Grasp, GraspSet, plan_grasps
from planner.grasping.handover import HandoverPose, handover_poses
from planner.motion.ik import IkSolver
from planner.motion.interpolation import interpolate
from planner.motion.stable_posture import PostureProblem, stable_posture
from planner.regrasp.graph import HOP_KINDS, HandoverNode, PlacementNode
from planner.regrasp.results import GraspProbe
from planner.regrasp.settings import HANDS_INDEX, PlannerSettings, Side
from planner.regrasp.state_checker import StateChecker
from planner.stability.effort import EffortEvaluator
from planner.robot.model import RobotModel, load_robot
from planner.scene.bodies import environment_boxes
from planner.scene.collision import CollisionWorld
from planner.scene.hand import hand_geometry
from planner.scene.objects import ObjectModel, build_object
from planner.scene.placements import PlacementError, instantiate_placements
from planner.stability.evaluator import StateEvaluator
from planner.stability.stances import Stance, solve_stance
from planner.transforms import pose7_to_matrix
from schemas.scenario import Scenario


#: The ready posture's hand is at most this far sideways from its shoulder (in front of it, not out to the side).
READY_LATERAL_M = 0.15
#: Arm postures drawn for the ready posture of an arm the shoulder x elbow grid does not fit.
READY_SAMPLES = 800


class Task:
    """Everything one regrasp task needs, built once and reused across hand configurations."""

    def __init__(self, scenario: Scenario, settings: PlannerSettings | None = None, *,
                 robot: RobotModel | None = None, threshold_m: float | None = None, seed: int | None = None):
        t0 = time.perf_counter()
        self.scenario = scenario
        self.settings = s = settings or PlannerSettings()
        self.robot = robot or load_robot(scenario.robot)
        self.stance: Stance = solve_stance(self.robot, scenario.stance)
        self.threshold_m = scenario.threshold_m if threshold_m is None else threshold_m
        self.seed = scenario.seed if seed is None else seed
        self.constrained = self.threshold_m > 0.0
        self.obj: ObjectModel = build_object(scenario.object)
        planning_threshold = self.threshold_m + s.planning_buffer_m if self.constrained else 0.0
        self.evaluator = StateEvaluator(self.robot, self.stance, planning_threshold, self.obj.mass_kg, self.obj.com_local)
        self.timings: dict[str, float] = {}
        #: Checks done for this task; a Counter, so that a helper process's counts add on (update adds).
        self.counters: Counter = Counter({"ik_solves": 0, "collision_states": 0, "com_states": 0})
        t1 = time.perf_counter()
        self.grasps: dict[Side, list[Grasp]] = {}
        self.grasp_cache_hit: dict[Side, bool] = {}
        for side in ("left", "right"):
            gs = plan_grasps(self.obj, self.robot, side, s.grasp)
            self.grasps[side] = list(gs.grasps)[: s.max_grasps]
            self.grasp_cache_hit[side] = gs.from_cache
        self.timings["grasps_s"] = time.perf_counter() - t1
        self.world = CollisionWorld.from_scenario(
            self.robot, scenario, self.obj, reference_postures=[(self.stance.base_pose, self.stance.q)],
            moving_joints=[*self.robot.spec.waist, *[j for a in self.robot.spec.arms.values() for j in a.chain],
                           *[a.gripper.joint for a in self.robot.spec.arms.values() if a.gripper is not None]],
        )
        #: static torques and grip, or None when the limits are switched off (``settings.limits``)
        self.limits: EffortEvaluator | None = (
            EffortEvaluator(self.robot, self.stance, self.obj.mass_kg, self.obj.com_local) if s.limits else None)
        self.checker = StateChecker(self.evaluator, self.world, self.stance.base_pose, self.constrained, self.counters,
                                    limits=self.limits)
        self.ik = IkSolver(self.robot, self.stance, s.ik, kinematics=self.world.kin)
        # The arm-only attempt is a cheap first try (few restarts); the waist joins when it fails.
        self.ik_arm_only = IkSolver(self.robot, self.stance, s.ik.model_copy(update={"use_waist": False, "restarts": s.arm_only_restarts}),
                                    kinematics=self.world.kin)
        self.home = self.stance.q.copy()
        #: pinocchio scratch of :meth:`stable_posture` (this task's own)
        self._posture_data = self.robot.create_data()
        #: the columns of each hand's jaw joint: one, or none for a rigid hand (index arrays, so writing a
        #: jaw value into a state is a no-op for a rigid hand; :meth:`put_jaw`)
        self.jaw = {side: np.array([self.robot.joint_index(g.joint)] if (g := self.robot.spec.arms[side].gripper) else [],
                                   dtype=int) for side in ("left", "right")}
        for side in ("left", "right"):
            self.home[self.jaw[side]] = self.robot.upper[self.jaw[side]]  # jaws open at home
        self.active = {side: np.concatenate([self.robot.waist_indices(), self.robot.arm_indices(side)]) for side in ("left", "right")}
        self.arm_only = {side: self.robot.arm_indices(side) for side in ("left", "right")}
        self.shoulder, self.reach = {}, {}
        data = self.robot.create_data()
        pin.framesForwardKinematics(self.robot.pin_model, data, self.robot.to_pin_q(self.stance.base_pose, self.home))
        for side in ("left", "right"):
            chain = self.robot.spec.arms[side].chain
            self.shoulder[side] = data.oMi[self.robot.pin_model.getJointId(chain[1])].translation.copy()
            # Longest TCP distance from the shoulder over the chain, plus what the waist adds.
            tcp = data.oMf[self.robot.frame_id(self.robot.spec.arms[side].tcp)].translation
            links = [data.oMi[self.robot.pin_model.getJointId(j)].translation for j in chain[1:]] + [tcp]
            self.reach[side] = float(sum(np.linalg.norm(b - a) for a, b in zip(links[:-1], links[1:]))) + s.waist_reach_m
        self.ready = {side: self._ready_posture(side) for side in ("left", "right")}
        t2 = time.perf_counter()
        self.placements, self.start_id, self.goal_id = self._placements()
        self._handover_cache: list[HandoverPose] | None = None
        #: Node validations shared by the hand configurations of this task (a node's outcome does not
        #: depend on the configuration, and each node draws from its own generator, so the outcome
        #: does not depend on the order either).
        self.node_cache: dict = {}
        #: (handover pose, giver grasp, giver) -> (q, hold, cause, margin) of the giver alone there,
        #: or None when its arm alone cannot reach
        self.giver_at: dict = {}
        #: placement node -> its grasp probe (see :func:`planner.regrasp.probes.probe_grasps`)
        self.grasp_probes: dict[PlacementNode, GraspProbe] = {}
        #: placement nodes whose probe missed and then let the waist help (:func:`planner.regrasp.probes.probe_grasps_with_waist`)
        self.waist_probed: set[PlacementNode] = set()
        self.timings["placements_s"] = time.perf_counter() - t2
        self.timings["setup_s"] = time.perf_counter() - t0

    # -- scene data ---------------------------------------------------------------------------
    def _placements(self) -> tuple[list[np.ndarray], int, int]:
        """Start, goal, then a few intermediate resting poses (table spots x yaws, diverse faces)."""
        sc = self.scenario
        start, goal = pose7_to_matrix(sc.start_pose), pose7_to_matrix(sc.goal_pose)
        # Spots are checked against obstacles only when chosen (few are used; checking all is slow).
        all_placements = instantiate_placements(self.obj, environment_boxes(sc)[: len(sc.tables)], start, goal)
        for what, T in (("start", start), ("goal", goal)):  # resting on a table, but perhaps inside an obstacle
            hit = self.world.object_pose_clear(T)
            if hit is not None:
                other = next((b for b in (hit.body_a, hit.body_b) if b.startswith("env:")), hit.body_b)
                raise PlacementError(f"the object at its {what} pose collides with {other.removeprefix('env:')!r}", end=what)
        spots = [p for p in all_placements if p.kind == "spot"]
        # Prefer spots where holding the object can be stable (the quick margin estimate reaches the
        # planning threshold: measured in the crouched scenario, only 80 of 992 spots do, and none
        # of the six nearest), then spots near the start-goal line, taking reference faces in turn
        # so regrasps can flip the object.
        mid = 0.5 * (start[:3, 3] + goal[:3, 3])
        needed = self.threshold_m + self.settings.planning_buffer_m if self.constrained else -np.inf
        if spots:
            T = np.array([p.T_world_obj for p in spots])
            unlikely = self.estimated_margins(T) < needed
            dist = np.linalg.norm(T[:, :2, 3] - mid[:2], axis=1)
            spots = [spots[k] for k in np.lexsort((dist, unlikely))]
        by_ref: dict[int, list] = {}
        for p in spots:
            by_ref.setdefault(p.reference, []).append(p)
        chosen: list[np.ndarray] = []
        while len(chosen) < self.settings.intermediate_placements and any(by_ref.values()):
            for ref in sorted(by_ref):
                while by_ref[ref] and len(chosen) < self.settings.intermediate_placements:
                    T = by_ref[ref].pop(0).T_world_obj
                    if self.world.object_pose_clear(T) is None:
                        chosen.append(T)
                        break
        return [start, goal, *chosen], 0, 1

    def _ready_posture(self, side: Side) -> np.ndarray | None:
        """A via posture with the hand raised above the tables in front of the shoulder.

        Most moves between the hanging home posture and a grasp above a table are blocked on the
        straight line by the table itself; home -> ready -> target usually is not, which spares a
        tree search. Found once per task: the collision-free posture closest to home whose hand clears
        the highest table top in front of its shoulder, among a small grid of shoulder pitch x elbow
        pitch (the arm's first two joints turning about the robot's lateral axis at home); for an arm
        without such a shoulder joint (one that raises the arm forward by a yaw and a roll together), or
        when the grid has no such posture, among arm postures drawn from a fixed seed.
        """
        tops = [b.pose[2] + b.size[2] / 2 for b in self.scenario.tables] or [0.8]
        clearance = max(tops) + self.settings.ready_height_m
        # Raised, and still in front of the tables' near edges: the hand rises before it goes over a top.
        edges = [b.pose[0] - b.size[0] / 2 for b in self.scenario.tables] or [np.inf]
        front = min(edges) - 0.05
        grid_joints = self._pitch_joints(side)
        tries = [] if grid_joints is None else [(lambda: self._ready_grid(grid_joints), grid_joints)]
        tries.append((lambda: self._ready_sampled(side), self.arm_only[side]))
        tcp_frame = self.robot.spec.arms[side].tcp
        for candidates, moving in tries:
            Q = candidates()
            _, frames = self.evaluator.kinematics(Q[0], list(moving)).com_and_frames(Q, (tcp_frame,))
            tcp = frames[tcp_frame][1]
            high = ((tcp[:, 2] >= clearance) & (tcp[:, 0] <= front)
                    & (np.abs(tcp[:, 1] - self.shoulder[side][1]) <= READY_LATERAL_M))
            if not high.any():
                continue
            free = ~self.world.check_batch(self.stance.base_pose, Q[high]).collides
            if not free.any():
                continue
            ok = Q[high][free]
            return ok[np.argmin(np.abs(ok - self.home).sum(axis=1))]
        return None

    def _pitch_joints(self, side: Side) -> tuple[int, int] | None:
        """(shoulder, elbow) wire columns: the first of the arm's first three joints whose axis is the robot's
        lateral one at home, and the next such joint after it within three; None when the arm has none."""
        chain = self.robot.spec.arms[side].chain
        model, data = self.robot.pin_model, self.robot.create_data()
        pin.computeJointJacobians(model, data, self.robot.to_pin_q(self.stance.base_pose, self.home))
        lateral = []
        for name in chain:
            jid = model.getJointId(name)
            axis = pin.getJointJacobian(model, data, jid, pin.WORLD)[3:, model.joints[jid].idx_v]
            lateral.append(abs(float(axis[1])) > 0.9)
        shoulder = next((k for k in range(min(3, len(chain))) if lateral[k]), None)
        if shoulder is None:
            return None
        elbow = next((k for k in range(shoulder + 1, min(shoulder + 4, len(chain))) if lateral[k]), None)
        if elbow is None:
            return None
        return self.robot.joint_index(chain[shoulder]), self.robot.joint_index(chain[elbow])

    def _ready_grid(self, joints: tuple[int, int]) -> np.ndarray:
        """Home with the shoulder pitch (``joints[0]``) in -0.3..-1.5 rad and the elbow pitch (``joints[1]``) in
        -0.8..-2.2 rad (within limits)."""
        shoulder, elbow = joints
        candidates = []
        for sp in np.linspace(-0.3, -1.5, 7):
            for ep in np.linspace(-0.8, -2.2, 8):
                q = self.home.copy()
                q[shoulder] = np.clip(sp, self.robot.lower[shoulder], self.robot.upper[shoulder])
                q[elbow] = np.clip(ep, self.robot.lower[elbow], self.robot.upper[elbow])
                candidates.append(q)
        return np.array(candidates)

    def _ready_sampled(self, side: Side) -> np.ndarray:
        """Home with the arm's joints drawn from a fixed seed: half around home (0.8 rad spread), half
        anywhere within the limits."""
        cols = self.arm_only[side]
        rng = np.random.default_rng([self.seed, 3, HANDS_INDEX[side]])
        n = READY_SAMPLES // 2
        lo, hi = self.robot.lower[cols], self.robot.upper[cols]
        Q = np.repeat(self.home[None], 2 * n, axis=0)
        Q[:n, cols] = np.clip(self.home[cols] + rng.normal(0.0, 0.8, (n, len(cols))), lo, hi)
        Q[n:, cols] = rng.uniform(lo, hi, (n, len(cols)))
        return Q

    @property
    def handover_poses(self) -> list[HandoverPose]:
        """Floating poses with compatible grasp pairs, computed on first use (single-arm plans never need them)."""
        if self._handover_cache is None:
            t0 = time.perf_counter()
            self._handover_cache = self._handover_poses()
            self.timings["handover_poses_s"] = time.perf_counter() - t0
        return self._handover_cache

    def _handover_poses(self) -> list[HandoverPose]:
        if not self.settings.handover_poses:
            return []
        right = GraspSet(self.obj.content_hash, "right", tuple(self.grasps["right"]), True, 0.0)
        left = GraspSet(self.obj.content_hash, "left", tuple(self.grasps["left"]), True, 0.0)
        poses = handover_poses(self.obj, right, left, hand_geometry(self.robot, "right"), hand_geometry(self.robot, "left"),
                               self.handover_anchor(), self.settings.handover, world=self.world)
        keep = self.settings.handover_pairs_per_pose
        out = []
        for hp in poses[: self.settings.handover_poses]:
            pairs = hp.pairs
            if len(pairs) > keep:  # evenly spread over the (sorted) pairs: hands at different places
                pairs = pairs[np.linspace(0, len(pairs) - 1, keep).astype(int)]
            out.append(HandoverPose(hp.id, hp.T_world_obj, pairs))
        return out

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

    def validations(self) -> dict:
        """What this copy of the task has worked out so far (for a worker process to hand back; see
        :meth:`adopt`): node validations, grasp probes, the givers alone at handover poses, the handover poses."""
        return {"nodes": dict(self.node_cache), "givers": dict(self.giver_at), "probes": dict(self.grasp_probes),
                "waist_probed": set(self.waist_probed),
                "handover_poses": self._handover_cache, "handover_poses_s": self.timings.get("handover_poses_s")}

    def adopt(self, validations: dict) -> None:
        """Take over what another copy of this task (a survey worker) worked out, so a plan after the
        survey does not repeat it. Outcomes do not depend on who computed them (each node draws from its
        own generator; handover poses are deterministic), so existing entries are kept as they are."""
        for k, v in validations["nodes"].items():
            self.node_cache.setdefault(k, v)
        for k, v in validations["givers"].items():
            self.giver_at.setdefault(k, v)
        for k, v in validations["probes"].items():
            mine = self.grasp_probes.get(k)
            if mine is None or (mine.q is None and v.q is not None):  # the other copy's waist reached it
                self.grasp_probes[k] = v
        self.waist_probed |= validations["waist_probed"]
        if self._handover_cache is None and validations["handover_poses"] is not None:
            self._handover_cache = validations["handover_poses"]
            self.timings["handover_poses_s"] = validations["handover_poses_s"]

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

    def solve_ik(self, side: Side, target: np.ndarray, seed: np.ndarray, rng: np.random.Generator,
                 arm_only: bool = False) -> np.ndarray | None:
        """IK for one TCP target. The arm alone is tried first: bending the waist moves the heavy
        torso and costs CoM margin, so the waist joins only when the arm cannot reach."""
        self.counters["ik_solves"] += 1
        res = self.ik_arm_only.solve_arm(side, target, seed, rng, rest_q=self.home)
        if res.q is None and not arm_only:
            self.counters["ik_solves"] += 1
            res = self.ik.solve_arm(side, target, seed, rng, rest_q=self.home)
        return res.q

    def stable_posture(self, q: np.ndarray, sides: Sequence[Side], T_obj: np.ndarray | None) -> np.ndarray | None:
        """The posture nearest ``q`` that keeps the TCPs of ``sides`` where ``q`` has them and the CoM
        margin of holding the object at ``T_obj`` (None: nothing held) at the planning threshold, moving
        the waist and the arms of ``sides``; None when there is none, or when the task is unconstrained or
        stable postures are off (:mod:`planner.motion.stable_posture`)."""
        if not (self.constrained and self.settings.stable_postures):
            return None
        self.counters["stable_postures"] += 1
        held = T_obj is not None and self.obj.mass_kg > 0.0
        problem = PostureProblem(self.robot, self.stance.base_pose, self.stance.polygon,
                                 self.obj.mass_kg if held else 0.0,
                                 T_obj[:3, :3] @ self.obj.com_local + T_obj[:3, 3] if held else None,
                                 data=self._posture_data)
        hands = {self.robot.spec.arms[s].tcp: self.tcp(q, s) for s in sides}
        columns = np.unique(np.concatenate([self.active[s] for s in sides]))
        out = stable_posture(problem, q, columns, hands, self.evaluator.threshold_m + self.settings.stable_posture_slack_m)
        if out is not None:
            self.counters["stable_postures_found"] += 1
        return out

    def line(self, a: np.ndarray, b: np.ndarray, n: int | None = None) -> np.ndarray:
        """``n`` states from a to b, both included (default: the approach samples)."""
        return interpolate(a, b, n or self.settings.approach_samples)

    def estimated_margins(self, T_obj: np.ndarray) -> np.ndarray:
        """Quick guesses of a held state's margin, the home posture plus the object at each pose
        of T_obj (N, 4, 4) (eq. 1)."""
        robot_com = np.broadcast_to(self.stance.robot_com, (len(T_obj), 3))
        return self.evaluator.with_object(robot_com, T_obj).margin

