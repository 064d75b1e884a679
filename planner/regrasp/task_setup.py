"""How a task's scene is set up: which resting placements it uses, the ready posture of each arm, its
handover poses. Free functions over a task being built (:class:`planner.regrasp.task.Task`, seen through
:class:`TaskParts`: what these functions read of it), run once per task.
"""

from __future__ import annotations

from typing import Mapping, Protocol

import numpy as np
import pinocchio as pin

from planner.grasping.grasps import Grasp, GraspSet
from planner.grasping.handover import HandoverPose, handover_poses
from planner.regrasp.settings import HANDS_INDEX, PlannerSettings, Side
from planner.robot.model import RobotModel
from planner.scene.bodies import environment_boxes
from planner.scene.collision import CollisionWorld
from planner.scene.hand import hand_geometry
from planner.scene.objects import ObjectModel
from planner.scene.placements import PlacementError, instantiate_placements
from planner.stability.evaluator import StateEvaluator
from planner.stability.stances import Stance
from planner.transforms import pose7_to_matrix
from schemas.scenario import Scenario

#: The ready posture's hand is at most this far sideways from its shoulder (in front of it, not out to the side).
READY_LATERAL_M = 0.15
#: Arm postures drawn for the ready posture of an arm the shoulder x elbow grid does not fit.
READY_SAMPLES = 800


class TaskParts(Protocol):
    """What the set-up reads of the task it sets up (each function, only the parts built before it runs)."""

    scenario: Scenario
    settings: PlannerSettings
    robot: RobotModel
    stance: Stance
    seed: int
    threshold_m: float
    constrained: bool
    obj: ObjectModel
    evaluator: StateEvaluator
    world: CollisionWorld
    grasps: Mapping[Side, tuple[Grasp, ...]]
    home: np.ndarray
    arm_only: Mapping[Side, np.ndarray]
    shoulder: Mapping[Side, np.ndarray]

    def estimated_margins(self, T_obj: np.ndarray) -> np.ndarray: ...

    def handover_anchor(self) -> np.ndarray: ...


def choose_placements(task: TaskParts) -> tuple[list[np.ndarray], int, int]:
    """Start, goal, then a few intermediate resting poses (table spots x yaws, diverse faces)."""
    sc = task.scenario
    start, goal = pose7_to_matrix(sc.start_pose), pose7_to_matrix(sc.goal_pose)
    # Spots are checked against obstacles only when chosen (few are used; checking all is slow).
    all_placements = instantiate_placements(task.obj, environment_boxes(sc)[: len(sc.tables)], start, goal)
    for what, T in (("start", start), ("goal", goal)):  # resting on a table, but perhaps inside an obstacle
        hit = task.world.object_pose_clear(T)
        if hit is not None:
            other = next((b for b in (hit.body_a, hit.body_b) if b.startswith("env:")), hit.body_b)
            raise PlacementError(f"the object at its {what} pose collides with {other.removeprefix('env:')!r}", end=what)
    spots = [p for p in all_placements if p.kind == "spot"]
    # Prefer spots where holding the object can be stable (the quick margin estimate reaches the
    # planning threshold; in a crouched stance few spots do, and often none of the nearest), then
    # spots near the start-goal line, taking reference faces in turn so regrasps can flip the object.
    mid = 0.5 * (start[:3, 3] + goal[:3, 3])
    needed = task.threshold_m + task.settings.planning_buffer_m if task.constrained else -np.inf
    if spots:
        T = np.array([p.T_world_obj for p in spots])
        unlikely = task.estimated_margins(T) < needed
        dist = np.linalg.norm(T[:, :2, 3] - mid[:2], axis=1)
        spots = [spots[k] for k in np.lexsort((dist, unlikely))]
    by_ref: dict[int, list] = {}
    for p in spots:
        by_ref.setdefault(p.reference, []).append(p)
    chosen: list[np.ndarray] = []
    while len(chosen) < task.settings.intermediate_placements and any(by_ref.values()):
        for ref in sorted(by_ref):
            while by_ref[ref] and len(chosen) < task.settings.intermediate_placements:
                T = by_ref[ref].pop(0).T_world_obj
                if task.world.object_pose_clear(T) is None:
                    chosen.append(T)
                    break
    return [start, goal, *chosen], 0, 1


def ready_posture(task: TaskParts, side: Side) -> np.ndarray | None:
    """A via posture with the hand raised above the tables in front of the shoulder.

    Most moves between the hanging home posture and a grasp above a table are blocked on the
    straight line by the table itself; home -> ready -> target usually is not, which spares a
    tree search. Found once per task: the collision-free posture closest to home whose hand clears
    the highest table top in front of its shoulder, among a small grid of shoulder pitch x elbow
    pitch (the arm's first two joints turning about the robot's lateral axis at home); for an arm
    without such a shoulder joint (one that raises the arm forward by a yaw and a roll together), or
    when the grid has no such posture, among arm postures drawn from a fixed seed.
    """
    tops = [b.pose[2] + b.size[2] / 2 for b in task.scenario.tables] or [0.8]
    clearance = max(tops) + task.settings.ready_height_m
    # Raised, and still in front of the tables' near edges: the hand rises before it goes over a top.
    edges = [b.pose[0] - b.size[0] / 2 for b in task.scenario.tables] or [np.inf]
    front = min(edges) - 0.05
    grid_joints = _pitch_joints(task, side)
    tries = [] if grid_joints is None else [(lambda: _ready_grid(task, grid_joints), grid_joints)]
    tries.append((lambda: _ready_sampled(task, side), task.arm_only[side]))
    tcp_frame = task.robot.spec.arms[side].tcp
    for candidates, moving in tries:
        Q = candidates()
        _, frames = task.evaluator.kinematics(Q[0], list(moving)).com_and_frames(Q, (tcp_frame,))
        tcp = frames[tcp_frame][1]
        high = ((tcp[:, 2] >= clearance) & (tcp[:, 0] <= front)
                & (np.abs(tcp[:, 1] - task.shoulder[side][1]) <= READY_LATERAL_M))
        if not high.any():
            continue
        free = ~task.world.check_batch(task.stance.base_pose, Q[high]).collides
        if not free.any():
            continue
        ok = Q[high][free]
        return ok[np.argmin(np.abs(ok - task.home).sum(axis=1))]
    return None


def _pitch_joints(task: TaskParts, side: Side) -> tuple[int, int] | None:
    """(shoulder, elbow) wire columns: the first of the arm's first three joints whose axis is the robot's
    lateral one at home, and the next such joint after it within three; None when the arm has none."""
    robot = task.robot
    chain = robot.spec.arms[side].chain
    model, data = robot.pin_model, robot.create_data()
    pin.computeJointJacobians(model, data, robot.to_pin_q(task.stance.base_pose, task.home))
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
    return robot.joint_index(chain[shoulder]), robot.joint_index(chain[elbow])


def _ready_grid(task: TaskParts, joints: tuple[int, int]) -> np.ndarray:
    """Home with the shoulder pitch (``joints[0]``) in -0.3..-1.5 rad and the elbow pitch (``joints[1]``) in
    -0.8..-2.2 rad (within limits)."""
    shoulder, elbow = joints
    lower, upper = task.robot.lower, task.robot.upper
    candidates = []
    for sp in np.linspace(-0.3, -1.5, 7):
        for ep in np.linspace(-0.8, -2.2, 8):
            q = task.home.copy()
            q[shoulder] = np.clip(sp, lower[shoulder], upper[shoulder])
            q[elbow] = np.clip(ep, lower[elbow], upper[elbow])
            candidates.append(q)
    return np.array(candidates)


def _ready_sampled(task: TaskParts, side: Side) -> np.ndarray:
    """Home with the arm's joints drawn from a fixed seed: half around home (0.8 rad spread), half
    anywhere within the limits."""
    cols = task.arm_only[side]
    rng = np.random.default_rng([task.seed, 3, HANDS_INDEX[side]])
    n = READY_SAMPLES // 2
    lo, hi = task.robot.lower[cols], task.robot.upper[cols]
    Q = np.repeat(task.home[None], 2 * n, axis=0)
    Q[:n, cols] = np.clip(task.home[cols] + rng.normal(0.0, 0.8, (n, len(cols))), lo, hi)
    Q[n:, cols] = rng.uniform(lo, hi, (n, len(cols)))
    return Q


def task_handover_poses(task: TaskParts) -> list[HandoverPose]:
    """Floating poses with compatible grasp pairs, each pose's pairs evenly thinned to the settings' count (every
    pair kept beside them, as 32-bit ids)."""
    s = task.settings
    if not s.handover_poses:
        return []
    right = GraspSet(task.obj.content_hash, "right", tuple(task.grasps["right"]), True, 0.0)
    left = GraspSet(task.obj.content_hash, "left", tuple(task.grasps["left"]), True, 0.0)
    poses = handover_poses(task.obj, right, left, hand_geometry(task.robot, "right"), hand_geometry(task.robot, "left"),
                           task.handover_anchor(), s.handover, world=task.world)
    keep = s.handover_pairs_per_pose
    out = []
    for hp in poses[: s.handover_poses]:
        pairs, every = hp.pairs, None
        if len(pairs) > keep:  # evenly spread over the (sorted) pairs: hands at different places
            pairs, every = pairs[np.linspace(0, len(pairs) - 1, keep).astype(int)], pairs.astype(np.int32)
        out.append(HandoverPose(hp.id, hp.T_world_obj, pairs, every))
    return out
