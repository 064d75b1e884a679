"""The CoM-constrained regrasp planner: the paper's planner, one hand configuration at a time.

Pipeline (one task = one scenario and one hand configuration):

1. **Task set-up** (:class:`Task`): robot, stance, object, grasps per hand (cached on
   disk), placements (start, goal and a few intermediate spots), handover poses,
   the collision world, IK solvers and the stability evaluator.
2. **Graph** (:mod:`planner.regrasp.graph`): abstract nodes after cheap checks.
3. **Lazy validation**: a node's key poses (pre-grasp, grasp, lift; at a handover the
   exchange) must be IK-feasible, collision-free and stable (margin >= threshold);
   an edge's motion comes from T-RRT (:mod:`planner.motion.trrt`), is shortcut, and is timed
   within the velocity/acceleration limits with the ZMP kept inside the polygon
   (:mod:`planner.motion.timing`). What fails is removed and the search runs again.
4. **Assembly** (:mod:`planner.regrasp.plan_assembly`): the timed pieces become the plan.

With ``threshold_m == 0`` this is the unconstrained planner: no margin constraint and
no margin cost (the paper's 0 mm comparison).
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable, Literal

import numpy as np
import pinocchio as pin
from pydantic import BaseModel, ConfigDict, Field

from schemas.scenario import Scenario

from planner.scene.collision import CollisionWorld
from planner.scene.collision import environment_boxes, hand_geometry
from planner.grasping.grasps import Grasp, GraspSet, GraspSettings, plan_grasps
from planner.grasping.handover import HandoverPose, HandoverSettings, handover_poses
from planner.scene.placements import PlacementError, instantiate_placements
from planner.motion.ik import IkSettings, IkSolver, key_pose_targets
from planner.regrasp.fork_share import share_with_child
from planner.forking import fork_is_safe, spare_cores
from planner.motion.ik_batch import BatchIkResult
from planner.scene.objects import ObjectModel, build_object
from planner.regrasp.plan_assembly import MotionPiece
from planner.regrasp.graph import (
    HOP_KINDS,
    REMOVE_NODE,
    Canceled,
    GraphSpec,
    GraphWeights,
    HandoverNode,
    PlacementNode,
    RegraspGraph,
    SearchResult,
    Validation,
)
from planner.robot.model import RobotModel, load_robot
from planner.motion.smoothing import SmoothingSettings, shortcut
from planner.stability.stances import Stance, solve_stance
from planner.stability.evaluator import HoldSpec, StateEvaluator
from planner.motion.timing import TimingSettings, time_path
from planner.transforms import inverse, pose7_to_matrix
from planner.motion.trrt import TrrtSettings, plan_motion

Side = Literal["left", "right"]
HANDS_INDEX: dict[str, int] = {"left": 0, "right": 1}
HANDS_OF: dict[str, tuple[Side, Side]] = {
    "left-left": ("left", "left"),
    "right-right": ("right", "right"),
    "left-right": ("left", "right"),
    "right-left": ("right", "left"),
}


class PlannerSettings(BaseModel):
    """Every knob of the regrasp planner, with defaults (SI units)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pregrasp_m: float = Field(0.06, gt=0, description="pre-grasp: back along the approach axis")
    lift_m: float = Field(0.06, gt=0, description="lift: straight up from the placement")
    approach_samples: int = Field(8, ge=2, description="states checked along approach and lift")
    max_grasps: int = Field(400, ge=1, description="grasps per hand kept for the graph (closest to the CoM first)")
    handover_pairs_per_pose: int = Field(12, ge=1, description="grasp pairs kept per handover pose (evenly spread)")
    intermediate_placements: int = Field(6, ge=0, description="table spots x yaws besides start and goal")
    handover: HandoverSettings = Field(default_factory=lambda: HandoverSettings(
        positions=((0.40, 0.0, 0.30), (0.36, 0.0, 0.38), (0.42, 0.0, 0.22), (0.32, 0.0, 0.47))))
    handover_poses: int = Field(96, ge=0, description="floating poses kept for handovers")
    weights: GraphWeights = Field(default_factory=GraphWeights)
    grasp: GraspSettings = Field(default_factory=GraspSettings)
    ik: IkSettings = Field(default_factory=lambda: IkSettings(restarts=2, max_iterations=60))
    # Larger steps and a stronger goal bias than T-RRT's exploration defaults: between key poses
    # the trees mostly need to connect, and edges are still checked every 0.02 rad (measured:
    # 2-5x less motion time on the built-in scenarios).
    trrt: TrrtSettings = Field(default_factory=lambda: TrrtSettings(max_iterations=300, step_rad=0.6, goal_bias=0.25))
    smoothing: SmoothingSettings = Field(default_factory=SmoothingSettings)
    timing: TimingSettings = Field(default_factory=TimingSettings)
    arm_only_restarts: int = Field(1, ge=0, description="random restarts of the arm-only IK attempt")
    motion_attempts: int = Field(
        2, ge=1, description="T-RRT runs per motion before it counts as failed: a run that reaches its round cap is "
        "one random draw, not proof (measured on crouched, where 80 % of transit extensions hit the table: with one "
        "run the return home failed on 2 of 20 seeds and took its goal node with it)")
    parallel_motions: bool = Field(
        True, description="plan the motions of a candidate path's hops in this process and one forked helper at once, "
        "where forking is safe and a second core exists (results are the same either way: each hop draws from its "
        "own generator)")
    waist_reach_m: float = Field(0.15, ge=0, description="how much farther the waist lets a hand reach, for the cheap reach filter")
    screen_valid: int = Field(4, ge=1, description="start/goal nodes validated up front until this many are valid")
    ready_height_m: float = Field(0.15, gt=0, description="ready posture: the hand this far above the highest table top")
    via_lift_m: float = Field(0.15, gt=0, description="via posture: the hand lifted this far above a motion's end")
    planning_buffer_m: float = Field(
        1e-3, ge=0, description="plan to threshold + this, so small IK residuals never bring a point below the threshold")


@dataclass
class KeyPoses:
    """Validated key configurations of a placement node."""

    q_pre: np.ndarray
    q_grasp_open: np.ndarray
    q_grasp: np.ndarray  # jaw closed
    q_lift: np.ndarray
    T_obj: np.ndarray  # the object where it rests
    T_obj_tcp: np.ndarray  # the actual grasp (TCP in the object frame) at q_grasp
    margin: float


@dataclass
class HandoverPoses:
    q_giver_at: np.ndarray  # giver at the handover pose, taker arm at home
    #: taker transit, approach, close, giver open, retreat, giver home; the two transits are
    #: planned (T-RRT) only once a path through this node is otherwise valid
    pieces: list[MotionPiece]
    q_after: np.ndarray  # taker holds, giver arm back home
    T_taker_obj_tcp: np.ndarray  # the taker's grasp relative to the object, as nominal
    margin: float
    motions_planned: bool = False


@dataclass
class PlannerResult:
    status: Literal["solved", "infeasible"]
    hands: str
    pieces: list[MotionPiece] = field(default_factory=list)
    cost: float = float("inf")
    min_margin_m: float | None = None
    failure_code: str | None = None
    message: str = ""
    failures: dict[str, int] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True)
class GraspProbe:
    """A placement node's IK solution at the grasp pose (jaw open), and the CoM margin of holding the
    object there: the arm alone first (:meth:`Task.probe_grasps`), the waist helping where it missed
    (:meth:`Task.probe_grasps_with_waist`, once a search reaches such a node); both None while no
    batched attempt reached (the node's own validation then solves it one by one)."""

    q: np.ndarray | None
    margin_m: float | None


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
                           *[a.gripper.joint for a in self.robot.spec.arms.values()]],
        )
        self.ik = IkSolver(self.robot, self.stance, s.ik, kinematics=self.world.kin)
        # The arm-only attempt is a cheap first try (few restarts); the waist joins when it fails.
        self.ik_arm_only = IkSolver(self.robot, self.stance, s.ik.model_copy(update={"use_waist": False, "restarts": s.arm_only_restarts}),
                                    kinematics=self.world.kin)
        self.home = self.stance.q.copy()
        self.jaw = {side: self.robot.joint_index(self.robot.spec.arms[side].gripper.joint) for side in ("left", "right")}
        for side in ("left", "right"):
            self.home[self.jaw[side]] = self.robot.upper[self.jaw[side]]  # jaws open at home
        self.active = {side: np.concatenate([self.robot.waist_indices(), self.robot.arm_indices(side)]) for side in ("left", "right")}
        self.arm_only = {side: self.robot.arm_indices(side) for side in ("left", "right")}
        self.ready = {side: self._ready_posture(side) for side in ("left", "right")}
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
        #: placement node -> its grasp probe (see :meth:`probe_grasps`)
        self.grasp_probes: dict[PlacementNode, GraspProbe] = {}
        #: placement nodes whose probe missed and then let the waist help (:meth:`probe_grasps_with_waist`)
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
        tree search. Found once per task on a small grid of shoulder pitch x elbow pitch: the
        collision-free posture closest to home whose hand clears the highest table top.
        """
        tops = [b.pose[2] + b.size[2] / 2 for b in self.scenario.tables] or [0.8]
        clearance = max(tops) + self.settings.ready_height_m
        chain = self.robot.spec.arms[side].chain
        shoulder, elbow = self.robot.joint_index(chain[1]), self.robot.joint_index(chain[4])
        candidates = []
        for sp in np.linspace(-0.3, -1.5, 7):
            for ep in np.linspace(-0.8, -2.2, 8):
                q = self.home.copy()
                q[shoulder] = np.clip(sp, self.robot.lower[shoulder], self.robot.upper[shoulder])
                q[elbow] = np.clip(ep, self.robot.lower[elbow], self.robot.upper[elbow])
                candidates.append(q)
        Q = np.array(candidates)
        _, frames = self.evaluator.kinematics(Q[0], [shoulder, elbow]).com_and_frames(Q, (self.robot.spec.arms[side].tcp,))
        tcp = frames[self.robot.spec.arms[side].tcp][1]
        # Raised, and still in front of the tables' near edges: the hand rises before it goes over a top.
        edges = [b.pose[0] - b.size[0] / 2 for b in self.scenario.tables] or [np.inf]
        high = (tcp[:, 2] >= clearance) & (tcp[:, 0] <= min(edges) - 0.05)
        if not high.any():
            return None
        free = ~self.world.check_batch(self.stance.base_pose, Q[high]).collides
        if not free.any():
            return None
        ok = Q[high][free]
        return ok[np.argmin(np.abs(ok - self.home).sum(axis=1))]

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
                               self.stance.base_pose[:3], self.settings.handover, world=self.world)
        keep = self.settings.handover_pairs_per_pose
        out = []
        for hp in poses[: self.settings.handover_poses]:
            pairs = hp.pairs
            if len(pairs) > keep:  # evenly spread over the (sorted) pairs: hands at different places
                pairs = pairs[np.linspace(0, len(pairs) - 1, keep).astype(int)]
            out.append(HandoverPose(hp.id, hp.T_world_obj, pairs))
        return out

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

    # -- evaluation helpers ---------------------------------------------------------------------
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
                res = self.world.check_batch(self.stance.base_pose, Q[idx], held=held,
                                             free_object_pose=None if held else free_object, grasping=grasping)
                self.counters["collision_states"] += len(idx)
                ok[idx] = ~res.collides
            return ok, batch.margin

        return check

    def classify(self, Q: np.ndarray, hold: HoldSpec | None, free_object: np.ndarray | None,
                 grasping: str | None = None) -> tuple[str | None, float]:
        """The first failing cause over states Q (com_margin before collision), and the min margin."""
        causes, margins = self.classify_groups(np.atleast_2d(Q), 1, hold, free_object, grasping)
        return causes[0], float(margins[0])

    def classify_groups(self, Q: np.ndarray, groups: int, hold: HoldSpec | None, free_object: np.ndarray | None,
                        grasping: str | None = None) -> tuple[list[str | None], np.ndarray]:
        """:meth:`classify` for ``groups`` equal runs of consecutive states of Q at once: each run's first
        failing cause and min margin. ``free_object`` is one pose, or one per state (N, 4, 4); runs that
        fail on the margin are not checked for collision."""
        k = len(Q) // groups
        batch = self.evaluator.evaluate(Q, hold)
        self.counters["com_states"] += len(Q)
        margins = batch.margin.reshape(groups, k).min(axis=1)
        unstable = ~batch.stable.reshape(groups, k).all(axis=1) if self.constrained else np.zeros(groups, dtype=bool)
        causes: list[str | None] = ["com_margin" if u else None for u in unstable]
        check = np.flatnonzero(~unstable)
        if check.size:
            rows = (check[:, None] * k + np.arange(k)).ravel()
            held = [(hold.tcp_side, hold.T_obj_tcp)] if hold is not None else []
            if free_object is not None and np.ndim(free_object) == 3:
                free_object = free_object[rows]
            res = self.world.check_batch(self.stance.base_pose, Q[rows], held=held,
                                         free_object_pose=None if held else free_object, grasping=grasping)
            self.counters["collision_states"] += len(rows)
            for g in check[res.collides.reshape(-1, k).any(axis=1)]:
                causes[g] = "collision"
        return causes, margins

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

    def line(self, a: np.ndarray, b: np.ndarray, n: int | None = None) -> np.ndarray:
        n = n or self.settings.approach_samples
        s = np.linspace(0.0, 1.0, n)[:, None]
        return a[None] * (1 - s) + b[None] * s

    def probe_grasps(self, nodes: list[PlacementNode]) -> dict[PlacementNode, GraspProbe]:
        """The IK solution at each node's grasp pose and the CoM margin of holding the object there, for
        the nodes not probed yet: batched descents per hand (:mod:`planner.motion.ik_batch`).

        The search weighs nodes by these margins before validating any: they bound a node's validated
        margin from above (its lift starts from this very state), so the cheapest path stays the
        cheapest once validated far more often than with the home-posture guess, and the search
        validates a few nodes where it validated every grasp of the start and goal placements
        (measured on the upright survey: 100 placement validations for left-left, 18 with the probes).
        """
        todo = [n for n in dict.fromkeys(nodes) if n not in self.grasp_probes]
        for side in ("left", "right"):
            mine = [n for n in todo if n.hand == side]
            if not mine:
                continue
            T_obj, targets = self._grasp_targets(side, mine)
            res = self._batch_arm_ik(side, targets, [self.node_seed(n) for n in mine])
            self._record_probes(side, mine, T_obj, res, self.arm_only[side])
        return self.grasp_probes

    def probe_grasps_with_waist(self, side: Side) -> None:
        """For every placement node of ``side`` whose probe missed (the arm alone did not reach) and
        that has no verdict yet: one batched descent with the waist helping, from home, then the same
        margin and jaw-closing probes; a node's validation starts from the posture found.

        Called when a search first validates such a node. Those nodes come last in the search (no
        margin, the highest cost), so most searches never get there; one that does validates them
        by the dozen (measured on crouched left-right, which has no key path: 67 of them, 8 ms each
        one by one, most failing on the margin at the grasp)."""
        mine = [n for n, p in self.grasp_probes.items()
                if p.q is None and n.hand == side and n not in self.waist_probed and n not in self.node_cache]
        if not mine:
            return
        self.waist_probed.update(mine)
        T_obj, targets = self._grasp_targets(side, mine)
        res = self.ik.batch.solve(side, targets, self.stance.base_pose, self.home, self.home)
        self.counters["ik_solves"] += len(mine)
        reached = np.flatnonzero(res.ok)
        if reached.size:
            self._record_probes(side, [mine[k] for k in reached], T_obj[reached], res.take(reached), self.active[side])

    def _grasp_targets(self, side: Side, nodes: list[PlacementNode]) -> tuple[np.ndarray, np.ndarray]:
        """The resting object's poses (N, 4, 4) at ``nodes`` and ``side``'s TCP targets (N, 4, 4) there."""
        T_obj = np.array([self.placements[n.placement] for n in nodes])
        return T_obj, T_obj @ np.array([self.grasps[side][n.grasp].T_obj_tcp for n in nodes])

    def _record_probes(self, side: Side, nodes: list[PlacementNode], T_obj: np.ndarray, res: BatchIkResult,
                       moving: np.ndarray) -> None:
        """Store the probes of ``nodes`` from their batched IK (``moving``: the columns it moved), with the
        margin of holding the object at the grasp; cache the verdicts the validation would reach first."""
        grasps = self.grasps[side]
        Q = res.q.copy()
        Q[:, self.jaw[side]] = [grasps[n.grasp].jaw_value for n in nodes]
        robot_com = self.evaluator.evaluate(Q, active=[*moving, self.jaw[side]]).robot_com
        held = self.evaluator.with_object(robot_com, T_obj)  # the object stays where it rests
        self.counters["com_states"] += len(nodes)
        for k, n in enumerate(nodes):
            self.grasp_probes[n] = GraspProbe(res.q[k] if res.ok[k] else None, float(held.margin[k]) if res.ok[k] else None)
            if res.ok[k] and not held.stable[k] and self.constrained:
                # Exactly what the node's validation would find first, from the same state.
                self.node_cache.setdefault(n, Validation(False, "com_margin", "holding the object at the grasp pose"))
        self._probe_jaw_closing(side, [n for k, n in enumerate(nodes) if res.ok[k] and n not in self.node_cache], grasps)

    def _probe_jaw_closing(self, side: Side, nodes: list[PlacementNode], grasps: list[Grasp]) -> None:
        """The node validation's second check, batched over probed nodes: the jaw closing on the resting
        object from the probe's posture (three states, robot alone for the margin, the object where it
        rests for collision, ``side``'s fingers allowed to touch it). A failure is cached as the
        validation's own verdict. Measured on one-legged left-right: 280 of 430 placement validations
        failed here, one by one, each after a search."""
        if not nodes:
            return
        jaw = self.jaw[side]
        q_open = np.array([self.grasp_probes[n].q for n in nodes])
        q_open[:, jaw] = self.robot.upper[jaw]
        q_closed = q_open.copy()
        q_closed[:, jaw] = [grasps[n.grasp].jaw_value for n in nodes]
        s = np.linspace(0.0, 1.0, 3)[None, :, None]  # :meth:`line` with three states, per node
        Q = (q_open[:, None] * (1 - s) + q_closed[:, None] * s).reshape(-1, self.robot.nq)
        T_obj = np.repeat(np.array([self.placements[n.placement] for n in nodes]), 3, axis=0)
        causes, margins = self.classify_groups(Q, len(nodes), None, T_obj, grasping=side)
        for n, cause, margin in zip(nodes, causes, margins):
            if cause:
                self.node_cache[n] = Validation(False, cause, "closing the jaw", margin_m=float(margin))

    def probe_givers(self, nodes: list[HandoverNode]) -> None:
        """The giver alone at each handover pose (:attr:`giver_at`), for the (pose, giver grasp) pairs
        of ``nodes`` not known yet, in batches: arm-only IK, margin and collisions holding the object.

        Most handover nodes fail right there (the giver's arm or the object against the body); one
        by one that was 4-10 ms per pair. Where the arm alone misses (the same two attempts as the
        one-by-one solve), the node's validation lets the waist help, as before."""
        keys = [k for k in dict.fromkeys((n.pose, n.giver_grasp, n.giver) for n in nodes) if k not in self.giver_at]
        for side in ("left", "right"):
            mine = [k for k in keys if k[2] == side]
            if not mine:
                continue
            grasps = self.grasps[side]
            T_obj = np.array([self.handover_poses[k[0]].T_world_obj for k in mine])
            targets = T_obj @ np.array([grasps[k[1]].T_obj_tcp for k in mine])
            res = self._batch_arm_ik(side, targets, [[self.seed, 2, k[0], k[1], HANDS_INDEX[side]] for k in mine])
            for k in np.flatnonzero(~res.ok):
                self.giver_at[mine[k]] = None  # the same two attempts the one-by-one solve makes missed
            ok = np.flatnonzero(res.ok)
            if not ok.size:
                continue
            Q = res.q[ok]
            Q[:, self.jaw[side]] = [grasps[mine[k][1]].jaw_value for k in ok]
            tcp = self.robot.spec.arms[side].tcp
            robot_com, frames = self.world.kin.com_and_frames(self.stance.base_pose, Q, [tcp])
            R, p = frames[tcp]
            T_tcp = np.zeros((len(ok), 4, 4))
            T_tcp[:, :3, :3], T_tcp[:, :3, 3], T_tcp[:, 3, 3] = R, p, 1.0
            held = self.evaluator.with_object(robot_com, T_obj[ok])
            collides = self.world.check_batch(self.stance.base_pose, Q, held=[(side, np.eye(4))],
                                              held_object_poses=T_obj[ok]).collides
            self.counters["com_states"] += len(ok)
            self.counters["collision_states"] += len(ok)
            for row, k in enumerate(ok):
                cause = ("com_margin" if self.constrained and not held.stable[row]
                         else "collision" if collides[row] else None)
                hold = HoldSpec(side, inverse(T_obj[k]) @ T_tcp[row])
                self.giver_at[mine[k]] = (Q[row], hold, cause, float(held.margin[row]))

    def _batch_arm_ik(self, side: Side, targets: np.ndarray, seeds: list) -> BatchIkResult:
        """:meth:`solve_ik` with the arm alone for many targets at once: the attempt from home, then,
        where it missed, the first restart from the draw the one-by-one solve would make with the
        generator seeded by ``seeds[k]``."""
        res = self.ik_arm_only.batch.solve(side, targets, self.stance.base_pose, self.home, self.home)
        self.counters["ik_solves"] += len(targets)
        missed = np.flatnonzero(~res.ok)
        if missed.size and self.ik_arm_only.settings.restarts > 0:
            cols = self.ik_arm_only.batch.active_columns(side)
            starts = np.array([self.ik_arm_only.attempt_start(1, self.home, cols, np.random.default_rng(seeds[k])) for k in missed])
            again = self.ik_arm_only.batch.solve(side, targets[missed], self.stance.base_pose, starts, self.home)
            res.q[missed], res.ok[missed] = again.q, again.ok
        return res

    def estimated_margins(self, T_obj: np.ndarray) -> np.ndarray:
        """Quick guesses of a held state's margin, the home posture plus the object at each pose
        of T_obj (N, 4, 4) (eq. 1)."""
        robot_com = np.broadcast_to(self.stance.robot_com, (len(T_obj), 3))
        return self.evaluator.with_object(robot_com, T_obj).margin


@dataclass
class _HopResult:
    """A hop's validation, and what planning it in the forked helper changed that this process needs."""

    validation: Validation
    handover: HandoverPoses | None = None  # the handover node's motions, planned by this hop
    counts: Counter = field(default_factory=Counter)  # the helper's check counters
    by_helper: bool = False


class HandConfigPlanner:
    """Plans one hand configuration of a task: graph, lazy validation, motions."""

    def __init__(self, task: Task, hands: str):
        if hands not in HANDS_OF:
            raise ValueError(f"unknown hands {hands!r}; valid: {', '.join(HANDS_OF)}")
        self.task = task
        self.hands = hands
        self.start_hand, self.goal_hand = HANDS_OF[hands]
        self.keyposes: dict[PlacementNode, KeyPoses] = {}
        self.handovers: dict[HandoverNode, HandoverPoses] = {}
        self._validated: dict = {}
        # Why start and goal nodes failed, to tell "the start is out of reach" from "no path".
        self.start_failures: Counter = Counter()
        self.goal_failures: Counter = Counter()
        self.start_ok = False
        self.goal_ok = False
        #: "start"/"goal" -> why no node there survived the cheap filters (set by graph_spec)
        self.end_problems: dict[str, str] = {}
        self.screen_failures: Counter = Counter()
        self._edges: dict = {}
        self.stage_s: dict[str, float] = {}
        #: Why the forked helper of :meth:`_prefetch_hops` failed, if it did (its hops are then planned here).
        self.helper_errors: list[str] = []
        self.hops_by_helper = 0
        self.dropped_known = 0  # nodes removed before the search, their failure known (_drop_known_failures)

    # -- graph construction ---------------------------------------------------------------------
    def _cheap_ok(self, side: Side, T_obj: np.ndarray, grasp: Grasp) -> bool:
        """Cheap filters before IK: the hand does not come from below the table top, and is in reach."""
        T_tcp = T_obj @ grasp.T_obj_tcp
        approach = T_tcp[:3, 2]
        if approach[2] > 0.3:  # approaching upwards: the palm would be under the object
            return False
        d = T_tcp[:3, 3] - self.task.shoulder[side]
        dist = float(np.linalg.norm(d))
        if dist > self.task.reach[side]:
            return False
        # The palm faces away from the shoulder: an approach pointing back at the robot needs a contorted wrist.
        return float(approach @ d) > -0.3 * dist

    def _unreachable_reason(self, end: str, T_obj: np.ndarray, side: Side) -> str:
        """Why no grasp of the object at an end pose passed the cheap filters, in words."""
        t = self.task
        grasps = t.grasps[side]
        if not grasps:
            return f"the {side} hand has no grasp of the object"
        dist = min(float(np.linalg.norm((T_obj @ g.T_obj_tcp)[:3, 3] - t.shoulder[side])) for g in grasps)
        if dist > t.reach[side]:
            return (f"the {end} pose is out of reach of the {side} hand: its nearest grasp is {dist:.2f} m from "
                    f"the shoulder, the arm and waist reach {t.reach[side]:.2f} m")
        return (f"the {end} pose cannot be grasped by the {side} hand: every grasp there approaches from below "
                f"or points back at the robot")

    def graph_spec(self) -> GraphSpec:
        t = self.task
        # A fixed order (a set's order of strings changes with each process's hash seed, and with it
        # the node order, the tie-break ranks and so the reported cost).
        sides: list[Side] = sorted({self.start_hand, self.goal_hand})
        nodes: list[PlacementNode] = []
        for p, T in enumerate(t.placements):
            for side in sides:
                for g, grasp in enumerate(t.grasps[side]):
                    if self._cheap_ok(side, T, grasp):
                        nodes.append(PlacementNode(p, g, side))
        for end, pid, hand in (("start", t.start_id, self.start_hand), ("goal", t.goal_id, self.goal_hand)):
            if not any(n.placement == pid and n.hand == hand for n in nodes):
                self.end_problems[end] = self._unreachable_reason(end, t.placements[pid], hand)
        handovers: list[HandoverNode] = []
        if self.start_hand != self.goal_hand:
            giver = self.start_hand
            for f, hp in enumerate(t.handover_poses):
                for r, l in hp.pairs:
                    gi, ti = (int(r), int(l)) if giver == "right" else (int(l), int(r))
                    handovers.append(HandoverNode(f, gi, ti, giver))
        positions = {p: tuple(T[:3, 3]) for p, T in enumerate(t.placements)}
        return GraphSpec(start=t.start_id, goal=t.goal_id, positions=positions, placement_nodes=nodes,
                         handover_nodes=handovers, start_hand=self.start_hand, goal_hand=self.goal_hand)

    # -- node validation ----------------------------------------------------------------------------
    def validate_node(self, node) -> Validation:
        """Validate a node once (cached across searches, e.g. for the K best solutions)."""
        if node in self._validated:
            return self._validated[node]
        t = self.task
        v = t.node_cache.get(node)
        if v is None:
            rng = np.random.default_rng(t.node_seed(node))
            v = self._validate_placement(node, rng) if isinstance(node, PlacementNode) else self._validate_handover(node, rng)
            t.node_cache[node] = v  # shared with the other hand configurations of this task
        if v.ok:
            if isinstance(node, PlacementNode):
                self.keyposes[node] = v.payload
            else:  # this planner plans and times the handover's motions into its own copy of the pieces
                self.handovers[node] = dataclasses.replace(
                    v.payload, pieces=[dataclasses.replace(p) for p in v.payload.pieces])
        if isinstance(node, PlacementNode):
            for pid, hand, counter, flag in ((t.start_id, self.start_hand, self.start_failures, "start_ok"),
                                             (t.goal_id, self.goal_hand, self.goal_failures, "goal_ok")):
                if node.placement == pid and node.hand == hand:
                    if v.ok:
                        setattr(self, flag, True)
                    else:
                        counter[v.cause or "ik"] += 1
        self._validated[node] = v
        return v

    def _validate_placement(self, node: PlacementNode, rng: np.random.Generator) -> Validation:
        t, s = self.task, self.task.settings
        side = node.hand
        grasp = t.grasps[side][node.grasp]
        T_obj = t.placements[node.placement]
        T_grasp = T_obj @ grasp.T_obj_tcp
        targets = key_pose_targets(T_grasp, approach_m=s.pregrasp_m, lift_m=s.lift_m)
        T_pre, T_lift = targets["pregrasp"], targets["lift"]
        # Cheapest decisive checks first: the grasp pose, then the held object there, then lift, then pre-grasp.
        probe = t.grasp_probes.get(node)
        if probe is not None and probe.q is None and node not in t.waist_probed:
            t.probe_grasps_with_waist(side)
            v = t.node_cache.get(node)
            if v is not None:
                return v  # the batch found what this validation would find first
            probe = t.grasp_probes[node]
        q_grasp = probe.q.copy() if probe is not None and probe.q is not None else t.solve_ik(side, T_grasp, t.home, rng)
        if q_grasp is None:
            return Validation(False, "ik", "grasp pose out of reach")
        q_grasp[t.jaw[side]] = t.robot.upper[t.jaw[side]]
        q_closed = q_grasp.copy()
        q_closed[t.jaw[side]] = grasp.jaw_value
        T_obj_tcp = inverse(T_obj) @ t.tcp(q_closed, side)
        hold = HoldSpec(side, T_obj_tcp)
        if t.constrained and not t.evaluator.evaluate_one(q_closed, hold).stable:
            return Validation(False, "com_margin", "holding the object at the grasp pose")
        cause, m2 = t.classify(t.line(q_grasp, q_closed, 3), None, T_obj, grasping=side)
        if cause:
            return Validation(False, cause, "closing the jaw", margin_m=m2)
        q_lift = t.solve_ik(side, T_lift, q_grasp, rng)
        if q_lift is None:
            return Validation(False, "ik", "lift pose out of reach")
        q_lift[t.jaw[side]] = grasp.jaw_value
        cause, m3 = t.classify(t.line(q_closed, q_lift), hold, None)
        if cause:
            return Validation(False, cause, "lift", margin_m=m3)
        q_pre = t.solve_ik(side, T_pre, q_grasp, rng)
        if q_pre is None:
            return Validation(False, "ik", "pre-grasp pose out of reach")
        q_pre[t.jaw[side]] = t.robot.upper[t.jaw[side]]
        cause, m1 = t.classify(np.vstack([q_pre[None], t.line(q_pre, q_grasp)]), None, T_obj, grasping=side)
        if cause:
            return Validation(False, cause, "approach", margin_m=m1)
        kp = KeyPoses(q_pre=q_pre, q_grasp_open=q_grasp, q_grasp=q_closed, q_lift=q_lift, T_obj=T_obj,
                      T_obj_tcp=T_obj_tcp, margin=min(m1, m2, m3))
        return Validation(True, margin_m=kp.margin, payload=kp)

    def _validate_handover(self, node: HandoverNode, rng: np.random.Generator) -> Validation:
        t, s = self.task, self.task.settings
        giver, taker = node.giver, node.taker
        gg, tg = t.grasps[giver][node.giver_grasp], t.grasps[taker][node.taker_grasp]
        T_obj = t.handover_poses[node.pose].T_world_obj
        T_g = T_obj @ gg.T_obj_tcp
        T_t = T_obj @ tg.T_obj_tcp
        # Arms without the waist first: a turning waist swings the idle arm into the table. With the
        # waist still the arms are independent, so the giver is solved and checked alone, once per
        # (pose, giver grasp): most handover nodes fail there (the object or the giver's arm
        # against the body), and the pairs of a pose share their giver grasps.
        giver_key = (node.pose, node.giver_grasp, giver)
        if giver_key not in t.giver_at:
            q_g = t.solve_ik(giver, T_g, t.home, np.random.default_rng([t.seed, 2, *giver_key[:2], HANDS_INDEX[giver]]),
                             arm_only=True)
            checked = None
            if q_g is not None:
                q_g[t.jaw[giver]] = gg.jaw_value
                hold = HoldSpec(giver, inverse(T_obj) @ t.tcp(q_g, giver))
                checked = (q_g, hold, *t.classify(q_g, hold, None))
            t.giver_at[giver_key] = checked
        checked = t.giver_at[giver_key]
        q_both = None
        if checked is not None:
            q_g, hold_g, cause, m0 = checked
            if cause:
                return Validation(False, cause, "giver at the handover pose", margin_m=m0)
            q_t = t.solve_ik(taker, T_t, q_g, rng, arm_only=True)
            if q_t is not None:
                q_both = q_g.copy()
                q_both[t.arm_only[taker]] = q_t[t.arm_only[taker]]
        if q_both is None:
            # Both arms with the waist, which they share.
            self.task.counters["ik_solves"] += 1
            res = t.ik.solve({giver: T_g, taker: T_t}, t.home, rng, rest_q=t.home)
            if res.q is None:
                return Validation(False, "ik", "handover pose out of reach for both hands")
            q_both = res.q
            q_both[t.jaw[giver]] = gg.jaw_value
            hold_g = HoldSpec(giver, inverse(T_obj) @ t.tcp(q_both, giver))
            q_g = q_both.copy()
            q_g[t.arm_only[taker]] = t.home[t.arm_only[taker]]
            cause, m0 = t.classify(q_g, hold_g, None)
            if cause:
                return Validation(False, cause, "giver at the handover pose", margin_m=m0)
        q_both[t.jaw[taker]] = t.robot.upper[t.jaw[taker]]
        # The giver at the handover pose with the taker arm still at home.
        q_giver_at = q_g
        G_g = hold_g.T_obj_tcp
        T_pre_t = key_pose_targets(T_t, approach_m=s.pregrasp_m)["pregrasp"]
        q_taker_pre = t.solve_ik(taker, T_pre_t, q_both, rng, arm_only=True)
        if q_taker_pre is None:
            return Validation(False, "ik", "taker pre-grasp out of reach")
        q_taker_pre[t.jaw[taker]] = t.robot.upper[t.jaw[taker]]
        T_pre_g = key_pose_targets(T_g, approach_m=s.pregrasp_m)["pregrasp"]
        q_giver_pre = t.solve_ik(giver, T_pre_g, q_both, rng, arm_only=True)
        if q_giver_pre is None:
            return Validation(False, "ik", "giver retreat out of reach")
        # Taker: home -> pre-grasp (T-RRT, arm only), approach, close.
        q_taker_pre_full = q_giver_at.copy()
        q_taker_pre_full[t.arm_only[taker]] = q_taker_pre[t.arm_only[taker]]
        approach_end = q_both.copy()
        cause, m1 = t.classify(t.line(q_taker_pre_full, approach_end), hold_g, None, grasping=taker)
        if cause:
            return Validation(False, cause, "taker approach", margin_m=m1)
        q_both_closed = approach_end.copy()
        q_both_closed[t.jaw[taker]] = tg.jaw_value
        G_t = inverse(T_obj) @ t.tcp(q_both_closed, taker)
        hold_both = HoldSpec("both", G_g if giver == "left" else G_t)
        hold_t = HoldSpec(taker, G_t)
        q_released = q_both_closed.copy()
        q_released[t.jaw[giver]] = t.robot.upper[t.jaw[giver]]
        cause, m2 = t.classify(t.line(q_both_closed, q_released, 3), hold_t, None, grasping=giver)
        if cause:
            return Validation(False, cause, "exchange", margin_m=m2)
        # Giver: retreat along its approach axis, then home (arm only).
        q_giver_back = q_released.copy()
        q_giver_back[t.arm_only[giver]] = q_giver_pre[t.arm_only[giver]]
        cause, m3 = t.classify(t.line(q_released, q_giver_back), hold_t, None, grasping=giver)
        if cause:
            return Validation(False, cause, "giver retreat", margin_m=m3)
        q_after = q_giver_back.copy()
        q_after[t.arm_only[giver]] = t.home[t.arm_only[giver]]
        q_close_open = approach_end
        pieces = [
            MotionPiece("transit", taker, np.array([q_giver_at, q_taker_pre_full]), giver, hold_g),
            MotionPiece("approach", taker, t.line(q_taker_pre_full, q_close_open, 2), giver, hold_g),
            MotionPiece("handover", "both", t.line(q_close_open, q_both_closed, 2), giver, hold_g),
            MotionPiece("handover", "both", t.line(q_both_closed, q_released, 2), "both", hold_both),
            MotionPiece("retreat", giver, t.line(q_released, q_giver_back, 2), taker, hold_t),
            MotionPiece("transit", giver, np.array([q_giver_back, q_after]), taker, hold_t),
        ]
        hp = HandoverPoses(q_giver_at=q_giver_at, pieces=pieces, q_after=q_after, T_taker_obj_tcp=G_t,
                           margin=min(m0, m1, m2, m3))
        return Validation(True, margin_m=hp.margin, payload=hp)

    # -- motions --------------------------------------------------------------------------------------
    def _motion(self, qa: np.ndarray, qb: np.ndarray, active: np.ndarray, hold: HoldSpec | None,
                free_object: np.ndarray | None, grasping: str | None, rng: np.random.Generator) -> np.ndarray | None:
        """A valid joint path qa -> qb (T-RRT, then shortcuts), or None."""
        t, s = self.task, self.task.settings
        validity = t.validity(hold, free_object, grasping, active=None)
        via = self._via_ready(qa, qb, active, validity, rng)
        if via is not None:
            return via
        trrt = s.trrt.model_copy(update={"margin_cost": t.constrained})
        for _ in range(s.motion_attempts):
            res = plan_motion(qa, qb, active, validity, t.robot.lower, t.robot.upper, rng, trrt,
                              should_stop=self._should_stop)
            if res.ok:
                break
        else:
            return None
        path = res.path
        if len(path) > 2:
            path = shortcut(path, validity, rng, s.smoothing, should_stop=self._should_stop).path
        return path

    def _via_ready(self, qa: np.ndarray, qb: np.ndarray, active: np.ndarray, validity,
                   rng: np.random.Generator) -> np.ndarray | None:
        """A short valid path through simple via postures, or None (then T-RRT searches).

        Candidates, cheapest first: the straight line; through the moving arm's ready posture
        (hand raised in front of the shoulder); through the hand lifted above either end
        (IK from that end). Most moves between table poses are one of these.
        """
        t = self.task
        sides = [side for side in ("left", "right") if np.all(np.isin(t.arm_only[side], active))]
        candidates: list[list[np.ndarray]] = [[qa, qb]]
        for side in sides:
            ready = None
            if t.ready[side] is not None:
                ready = qa.copy()
                ready[t.arm_only[side]] = t.ready[side][t.arm_only[side]]
                ready[t.jaw[side]] = qa[t.jaw[side]]
                candidates.append([qa, ready, qb])
            up_a, up_b = self._lifted(qa, side, rng), self._lifted(qb, side, rng)
            if up_a is not None and up_b is not None:
                candidates.append([qa, up_a, up_b, qb])
            if ready is not None and up_b is not None:
                candidates.append([qa, ready, up_b, qb])
            if ready is not None and up_a is not None:
                candidates.append([qa, up_a, ready, qb])
        for waypoints in candidates:
            if self._path_valid(waypoints, validity):
                return np.array(waypoints)
        return None

    def _lifted(self, q: np.ndarray, side: Side, rng: np.random.Generator) -> np.ndarray | None:
        """``q`` with ``side``'s hand raised by ``via_lift_m`` (arm-only IK from q), or None."""
        t = self.task
        T = t.tcp(q, side)
        T[2, 3] += t.settings.via_lift_m
        res = t.ik_arm_only.solve_arm(side, T, q, rng, rest_q=q)
        t.counters["ik_solves"] += 1
        if res.q is None:
            return None
        out = res.q
        out[t.jaw[side]] = q[t.jaw[side]]
        return out

    def _path_valid(self, waypoints: list[np.ndarray], validity) -> bool:
        res = self.task.settings.trrt.edge_resolution_rad
        states = [waypoints[0][None]]
        for a, b in zip(waypoints[:-1], waypoints[1:]):
            n = max(int(np.ceil(np.abs(b - a).max() / res)), 1)
            f = np.linspace(0.0, 1.0, n + 1)[1:, None]
            states.append(a[None] * (1 - f) + b[None] * f)
        ok, _ = validity(np.vstack(states))
        return bool(np.all(ok))

    def _timed(self, piece: MotionPiece) -> MotionPiece | None:
        """Time a piece; None if the ZMP or the dense margin check cannot be kept."""
        t = self.task
        timed = time_path(piece.waypoints, t.robot, t.evaluator, piece.hold, t.settings.timing,
                          threshold_m=t.evaluator.threshold_m if t.constrained else -np.inf)
        if not timed.ok:
            return None
        piece.waypoints = timed.Q
        piece.timed = True  # type: ignore[attr-defined]
        return piece

    def validate_edge(self, a, b, kind: str) -> Validation:
        t = self.task
        rng = np.random.default_rng(t.hop_seed(a, b, kind))
        pieces: list[MotionPiece] = []
        if a is None:  # home -> first node's pre-grasp
            kp = self.keyposes[b]
            path = self._motion(t.home, kp.q_pre, t.active[b.hand], None, kp.T_obj, None, rng)
            if path is None:
                return Validation(False, "motion", "home to the first pre-grasp")
            pieces.append(MotionPiece("transit", b.hand, path, "none", None))
        elif b is None:  # last node: release, retreat, home
            kp = self.keyposes[a]
            path = self._motion(kp.q_pre, self._home_from(kp.q_pre, a.hand), t.active[a.hand], None, kp.T_obj, None, rng)
            if path is None:
                return Validation(False, "motion", "back home after placing")
            pieces.append(MotionPiece("transit", a.hand, path, "none", None))
        elif kind == "transit":  # regrasp at the same placement
            ka, kb = self.keyposes[a], self.keyposes[b]
            path = self._motion(ka.q_pre, self._with_arm_of(kb.q_pre, ka.q_pre, b.hand), t.active[b.hand], None, ka.T_obj, None, rng)
            if path is None:
                return Validation(False, "motion", "regrasp transit")
            pieces.append(MotionPiece("transit", b.hand, path, "none", None))
        elif kind == "transfer":
            ka, kb = self.keyposes[a], self.keyposes[b]
            hold = HoldSpec(a.hand, ka.T_obj_tcp)
            path = self._motion(ka.q_lift, self._with_arm_of(kb.q_lift, ka.q_lift, a.hand), t.active[a.hand], hold, None, None, rng)
            if path is None:
                return Validation(False, "motion", "transfer between placements")
            pieces.append(MotionPiece("transfer", a.hand, path, a.hand, hold))
        elif kind == "handover" and isinstance(b, HandoverNode):
            ka, hp = self.keyposes[a], self.handovers[b]
            if not self._plan_handover_motions(b):
                return Validation(False, "motion", "handover transits", payload=REMOVE_NODE)
            hold = HoldSpec(a.hand, ka.T_obj_tcp)
            cause, _ = t.classify(hp.q_giver_at, hold, None)
            if cause:
                return Validation(False, cause, "giver at the handover with its own grasp")
            path = self._motion(ka.q_lift, hp.q_giver_at, t.active[a.hand], hold, None, None, rng)
            if path is None:
                return Validation(False, "motion", "transfer to the handover pose")
            pieces.append(MotionPiece("transfer", a.hand, path, a.hand, hold))
        elif kind == "handover":  # handover node -> placement node of the taker
            hp, kb = self.handovers[a], self.keyposes[b]
            hold = HoldSpec(b.hand, hp.T_taker_obj_tcp)
            target = self._with_arm_of(kb.q_lift, hp.q_after, b.hand)
            cause, _ = t.classify(target, hold, None)
            if cause:
                return Validation(False, cause, "taker at the lift pose with the handover grasp")
            path = self._motion(hp.q_after, target, t.active[b.hand], hold, None, None, rng)
            if path is None:
                return Validation(False, "motion", "transfer from the handover to the goal")
            pieces.append(MotionPiece("transfer", b.hand, path, b.hand, hold))
        else:  # pragma: no cover - the graph only makes the kinds above
            return Validation(False, "motion", f"unknown edge kind {kind}")
        timed = []
        for p in pieces:
            tp = self._timed(p)
            if tp is None:
                return Validation(False, "com_margin" if t.constrained else "motion", "timing: ZMP or dense margin")
            timed.append(tp)
        return Validation(True, payload=timed)

    def _plan_handover_motions(self, node: HandoverNode) -> bool:
        """Plan the taker's way to its pre-grasp and the giver's way home (arm only, waist fixed)."""
        hp = self.handovers[node]
        if hp.motions_planned:
            return True
        t = self.task
        rng = np.random.default_rng([*t.node_seed(node), len(HOP_KINDS)])  # the node's, whichever hop plans them
        for i, piece in ((0, hp.pieces[0]), (5, hp.pieces[5])):
            side = node.taker if i == 0 else node.giver
            qa, qb = piece.waypoints[0], piece.waypoints[-1]
            path = self._motion(qa, qb, t.arm_only[side], piece.hold, None, None, rng)
            if path is None:
                return False
            piece.waypoints = path
        hp.motions_planned = True
        return True

    def _with_arm_of(self, q_target: np.ndarray, q_current: np.ndarray, side: Side) -> np.ndarray:
        """q_target for the waist and ``side``'s arm and jaw; everything else as in q_current."""
        out = q_current.copy()
        idx = self.task.active[side]
        out[idx] = q_target[idx]
        out[self.task.jaw[side]] = q_target[self.task.jaw[side]]
        return out

    def _home_from(self, q: np.ndarray, side: Side) -> np.ndarray:
        out = q.copy()
        out[self.task.active[side]] = self.task.home[self.task.active[side]]
        return out

    _should_stop: Callable[[], bool] = staticmethod(lambda: False)

    # -- search and assembly ----------------------------------------------------------------------------
    def plan(self, *, max_iterations: int, time_limit_s: float, should_stop: Callable[[], bool] = lambda: False,
             on_iteration: Callable[[int, dict], None] | None = None, solutions: int = 1) -> PlannerResult:
        """The best plan of this hand configuration, and up to ``solutions - 1`` next-best ones."""
        t0 = time.perf_counter()
        self._should_stop = should_stop  # type: ignore[assignment]
        spec = self.graph_spec()
        if self.end_problems:  # an end no hand pose can reach: no search can succeed
            end = "start" if "start" in self.end_problems else "goal"
            return PlannerResult("infeasible", self.hands, failure_code=f"{end.upper()}_INVALID", message=self.end_problems[end],
                                 failures={"ik": len(self.end_problems)}, stats={"time_s": time.perf_counter() - t0})
        spec = self.screen(spec, should_stop)
        weights = self.task.settings.weights
        if not self.task.constrained:  # the unconstrained planner: no margin cost either
            weights = dataclasses.replace(weights, margin=0.0)
        graph = RegraspGraph(spec, weights)
        self.prepare_search(graph)
        t_search = time.perf_counter()
        found: list[SearchResult] = []
        res: SearchResult | None = None
        failures: Counter = Counter(self.screen_failures)
        iterations = 0
        while len(found) < solutions:
            remaining = time_limit_s - (time.perf_counter() - t0)
            if found and remaining <= 0:
                break
            res = graph.search(
                self._timed_node, self._timed_edge, max_iterations=max_iterations, time_limit_s=max(remaining, 0.01),
                should_stop=should_stop, on_iteration=(lambda i, f: on_iteration(i, dict(f))) if on_iteration else None,
                banned_paths=[tuple(r.path) for r in found],
                prefetch_edges=self._prefetch_hops if self._may_share_hops() else None,
            )
            failures.update(res.failures)
            iterations += res.iterations
            if res.status != "solved":
                break
            found.append(res)
        stage = dict(self.stage_s)
        stage["search_s"] = max(time.perf_counter() - t_search - sum(stage.values()), 0.0)
        stats = {"graph_nodes": res.graph_nodes if res else 0, "graph_edges": res.graph_edges if res else 0,
                 "search_iterations": iterations, "nodes_validated": len(self._validated) - self.dropped_known,
                 "nodes_dropped_known": self.dropped_known, "edges_validated": len(self._edges),
                 "hops_by_helper": self.hops_by_helper, "stage_s": stage, "time_s": time.perf_counter() - t0}
        if self.helper_errors:
            stats["helper_errors"] = list(self.helper_errors)
        if not found:
            return PlannerResult("infeasible", self.hands, failure_code=res.code if res else "NO_PATH",
                                 message=res.message if res else "", failures=dict(failures), stats=stats)
        t_asm = time.perf_counter()
        best = found[0]
        out = PlannerResult("solved", self.hands, pieces=self._assemble_pieces(best), cost=best.cost,
                            failures=dict(failures), stats=stats)
        out.others = [(r.cost, self._assemble_pieces(r)) for r in found[1:]]  # type: ignore[attr-defined]
        stats["stage_s"]["assembly_s"] = time.perf_counter() - t_asm
        return out

    def _timed_node(self, node) -> Validation:
        t0 = time.perf_counter()
        try:
            return self.validate_node(node)
        finally:
            self.stage_s["nodes_s"] = self.stage_s.get("nodes_s", 0.0) + time.perf_counter() - t0

    def _may_share_hops(self) -> bool:
        return self.task.settings.parallel_motions and spare_cores() > 0 and fork_is_safe()

    def _prefetch_hops(self, hops: list[tuple]) -> None:
        """Plan a candidate path's motions in this process and a forked helper at once
        (:func:`planner.regrasp.fork_share.share_with_child`), longest first so that neither process is left
        with a long one at the end: a hop into a handover whose own motions are not planned yet (it
        plans them too: two T-RRT motions, measured 1.3 s of upright left-right's 2.1 s), then the
        transits (T-RRT around the table), then the rest. Each hop draws from its own generator, so
        the verdicts are those the search would get one by one; a hop after a failing one is planned
        for nothing, and kept for later paths."""

        def plans_handover(hop: tuple) -> bool:
            b = hop[1]
            return isinstance(b, HandoverNode) and not self.handovers[b].motions_planned

        todo = sorted((h for h in hops if h not in self._edges), key=lambda h: (not plans_handover(h), h[2] != "transit"))
        if len(todo) < 2:
            return
        t0 = time.perf_counter()
        results, error = share_with_child(todo, self._hop_work, self._should_stop)
        for k, res in results.items():
            b = todo[k][1]
            if res.handover is not None and not self.handovers[b].motions_planned:
                self.handovers[b] = res.handover
            self.task.counters.update(res.counts)
            self.hops_by_helper += res.by_helper
            self._edges[todo[k]] = res.validation
        if error is not None:
            self.helper_errors.append(error.strip().splitlines()[-1])
        self.stage_s["motions_s"] = self.stage_s.get("motions_s", 0.0) + time.perf_counter() - t0

    def _hop_work(self, hop: tuple, in_child: bool) -> _HopResult:
        """One hop's validation; from the helper also what it changed that the parent needs: the
        handover's planned motions and the check counters."""
        a, b, kind = hop
        if not in_child:
            return _HopResult(self.validate_edge(a, b, kind))
        before = Counter(self.task.counters)
        v = self.validate_edge(a, b, kind)
        hp = self.handovers.get(b) if isinstance(b, HandoverNode) else None
        return _HopResult(v, hp if hp is not None and hp.motions_planned else None,
                          Counter(self.task.counters) - before, True)

    def _timed_edge(self, a, b, kind: str) -> Validation:
        """Edge validation, cached across searches (the K best solutions share their motions)."""
        key = (a, b, kind)
        if key not in self._edges:
            t0 = time.perf_counter()
            self._edges[key] = self.validate_edge(a, b, kind)
            self.stage_s["motions_s"] = self.stage_s.get("motions_s", 0.0) + time.perf_counter() - t0
        return self._edges[key]

    def screen(self, spec: GraphSpec, should_stop: Callable[[], bool] = lambda: False, want: int | None = None) -> GraphSpec:
        """Validate start and goal nodes up front, in grasp order (closest to the object's CoM first),
        until a few are valid.

        Most failures happen where the object rests at the start and goal; screening them in one
        pass spares a graph search per failed node. Nodes found invalid leave the spec.
        """
        t = self.task
        bad: set = set()
        for pid, hand in ((t.start_id, self.start_hand), (t.goal_id, self.goal_hand)):
            cands = [n for n in spec.placement_nodes if n.placement == pid and n.hand == hand]
            cands.sort(key=lambda n: n.grasp)  # grasps come sorted by their distance to the CoM
            found = 0
            for n in cands:
                if found >= (want or t.settings.screen_valid):
                    break
                if should_stop():
                    raise Canceled()
                v = self.validate_node(n)
                if v.ok:
                    found += 1
                else:
                    bad.add(n)
                    self.screen_failures[v.cause or "ik"] += 1
        return dataclasses.replace(spec, placement_nodes=[n for n in spec.placement_nodes if n not in bad])

    def prepare_search(self, graph: RegraspGraph) -> None:
        """Before the first search: probe and weigh the nodes, then remove those whose failure that made known."""
        self._weigh_nodes(graph)
        self._drop_known_failures(graph)

    def _weigh_nodes(self, graph: RegraspGraph) -> None:
        """Before any node is validated, weight placement nodes by the margin of holding the object at
        their grasp (:meth:`Task.probe_grasps`), so the search tries stable ones first. A node whose
        probe missed gets no margin at all (the highest margin cost): it is validated only when the
        nodes that reach their grasp have run out."""
        t = self.task
        handovers = [n for n in graph.nodes() if isinstance(n, HandoverNode)]
        if handovers:
            t.probe_givers(handovers)
        if graph.w.margin == 0.0:
            return
        nodes = [n for n in graph.nodes() if isinstance(n, PlacementNode)]
        probes = t.probe_grasps(nodes)
        for node in nodes:
            m = probes[node].margin_m
            graph._apply_margin_cost(node, 0.0 if m is None else m)
        for node in handovers:  # the giver's state there is one of the handover's states
            giver = t.giver_at.get((node.pose, node.giver_grasp, node.giver))
            if giver is not None:
                graph._apply_margin_cost(node, giver[3])

    def _drop_known_failures(self, graph: RegraspGraph) -> None:
        """Remove, before the search, the nodes already known to fail: those another hand configuration
        of the task validated, the grasps whose probe found the held object unstable, the handovers whose
        giver the probe found unstable or colliding (:meth:`validate_node` returns their verdict without
        new IK). The search would remove each only when it lay on the cheapest path, one search per
        node: measured on crouched left-right, which has no valid handover, 400 searches (the iteration
        cap) before it gave up. Counted like the screening's failures."""
        t = self.task
        for node in list(graph.nodes()):
            if not isinstance(node, (PlacementNode, HandoverNode)):  # hubs, source and sink
                continue
            v = t.node_cache.get(node)
            known = v is not None and not v.ok
            if isinstance(node, HandoverNode) and not known:
                giver = t.giver_at.get((node.pose, node.giver_grasp, node.giver))
                known = giver is not None and giver[2] is not None
            if known:
                v = self.validate_node(node)  # the cached verdict, and the start/goal bookkeeping
                if not v.ok:
                    graph.remove_node(node)
                    self.screen_failures[v.cause or "ik"] += 1
                    self.dropped_known += 1

    def _assemble_pieces(self, res: SearchResult) -> list[MotionPiece]:
        """Key-pose moves and planned motions in execution order (the builder tracks the object)."""
        t = self.task
        out: list[MotionPiece] = []
        path = res.path
        edges = iter([e.payload for e in res.edges])  # timed pieces, one list per hop, in order
        out.extend(next(edges))  # home -> first pre-grasp
        for i, node in enumerate(path):
            if isinstance(node, HandoverNode):
                out.extend(self._timed_copy(p) for p in self.handovers[node].pieces)
                out.extend(next(edges))  # handover -> taker's lift pose
                continue
            kp = self.keyposes[node]
            side = node.hand
            prev = path[i - 1] if i > 0 else None
            nxt = path[i + 1] if i + 1 < len(path) else None
            if not self._carried(prev, node):
                # Pick: approach, close the jaw, lift.
                out.append(self._timed_copy(MotionPiece("approach", side, t.line(kp.q_pre, kp.q_grasp_open, 2), "none", None)))
                out.append(self._timed_copy(MotionPiece("approach", side, t.line(kp.q_grasp_open, kp.q_grasp, 2), "none", None)))
                out.append(self._timed_copy(MotionPiece("transfer", side, t.line(kp.q_grasp, kp.q_lift, 2), side,
                                                        HoldSpec(side, kp.T_obj_tcp))))
            if nxt is not None and self._carried(node, nxt):
                out.extend(next(edges))  # carry to the next placement or to the handover pose
                continue
            # Place: lower, open the jaw, retreat; then the regrasp transit or the way home.
            here = out[-1].waypoints[-1]
            down = self._with_arm_of(kp.q_grasp, here, side)
            opened = down.copy()
            opened[t.jaw[side]] = t.robot.upper[t.jaw[side]]
            out.append(self._timed_copy(MotionPiece("transfer", side, t.line(here, down, 2), side, HoldSpec(side, kp.T_obj_tcp))))
            out.append(self._timed_copy(MotionPiece("retreat", side, t.line(down, opened, 2), "none", None)))
            out.append(self._timed_copy(MotionPiece("retreat", side, t.line(opened, self._with_arm_of(kp.q_pre, opened, side), 2), "none", None)))
            out.extend(next(edges))
        return out

    @staticmethod
    def _carried(a, b) -> bool:
        """Whether the object stays in hand from node a to node b (transfer or handover)."""
        if a is None or b is None:
            return False
        if isinstance(a, HandoverNode) or isinstance(b, HandoverNode):
            return True
        return a.grasp == b.grasp and a.hand == b.hand and a.placement != b.placement

    def _timed_copy(self, piece: MotionPiece) -> MotionPiece:
        if getattr(piece, "timed", False):
            return piece
        tp = self._timed(MotionPiece(piece.kind, piece.hand, piece.waypoints, piece.holding, piece.hold))
        if tp is None:  # short straight pieces were validated densely already; time them kinematically
            from planner.motion.timing import time_parameterize

            _, Q = time_parameterize(piece.waypoints, self.task.robot, self.task.settings.timing)
            piece.waypoints = Q
            piece.timed = True  # type: ignore[attr-defined]
            return piece
        return tp
