"""The regrasp planner's settings, and the hand configurations it plans."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from planner.grasping.grasps import GraspSettings
from planner.grasping.handover import HandoverSettings
from planner.motion.ik import IkSettings
from planner.motion.smoothing import SmoothingSettings
from planner.motion.timing import TimingSettings
from planner.regrasp.timing.settings import PlanTimingSettings
from planner.motion.trrt import TrrtSettings
from planner.regrasp.graph import GraphWeights

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
    approach_samples: int = Field(8, ge=2, description="states checked along approach and lift (at least)")
    line_check_rad: float = Field(0.005, gt=0, description="largest per-joint change between the states checked along "
                                  "approach, lift and retreat: as dense as the timed samples (1 rad/s x 5 ms), so "
                                  "a graze between two checked states does not reach the plan")
    max_grasps: int = Field(400, ge=1, description="grasps per hand kept for the graph (closest to the CoM first)")
    handover_pairs_per_pose: int = Field(12, ge=1, description="grasp pairs kept per handover pose (evenly spread)")
    handover_direct_pairs_per_pose: int = Field(
        12, ge=0, description="more grasp pairs per handover pose, each of a giver grasp the task may start with and a "
        "taker grasp it may end with (those found valid first, then in grasp order): the pairs a handover without a "
        "table regrasp needs, rarely among the evenly spread ones")
    intermediate_placements: int = Field(6, ge=0, description="table spots x yaws besides start and goal")
    handover: HandoverSettings = Field(default_factory=lambda: HandoverSettings(
        positions=((0.40, 0.0, 0.30), (0.36, 0.0, 0.38), (0.42, 0.0, 0.22), (0.32, 0.0, 0.47))))
    handover_poses: int = Field(96, ge=0, description="floating poses kept for handovers")
    handover_giver_postures: int = Field(
        6, ge=0, description="more giver postures (restarts of the giver's IK) tried at a handover node whose exchange "
        "collides with the giver as first solved: which elbow the first solve finds decides whether the taker "
        "reaches in")
    weights: GraphWeights = Field(default_factory=GraphWeights)
    grasp: GraspSettings = Field(default_factory=GraspSettings)
    ik: IkSettings = Field(default_factory=lambda: IkSettings(restarts=2, max_iterations=60))
    # Larger steps and a stronger goal bias than T-RRT's exploration defaults: between key poses
    # the trees mostly need to connect, and edges are still checked every 0.02 rad
    # (benchmarks/bench_motion.py shows what it saves).
    trrt: TrrtSettings = Field(default_factory=lambda: TrrtSettings(max_iterations=300, step_rad=0.6, goal_bias=0.25))
    smoothing: SmoothingSettings = Field(default_factory=SmoothingSettings)
    timing: TimingSettings = Field(default_factory=TimingSettings)
    plan_timing: PlanTimingSettings = Field(default_factory=PlanTimingSettings)
    arm_only_restarts: int = Field(1, ge=0, description="random restarts of the arm-only IK attempt")
    motion_attempts: int = Field(
        2, ge=1, description="T-RRT runs per motion before it counts as failed: a run that reaches its round cap is "
        "one random draw, not proof: where most transit extensions hit the table, one failed run would "
        "remove a goal node that a second run reaches")
    parallel_motions: bool = Field(
        True, description="plan the motions of a candidate path's hops, and the timing's quicker paths of the solved "
        "plan's motions and its runs' timings, in this process and one forked helper at once, where forking is safe "
        "and a second core exists (results are the same either way: each hop and each motion draws from its own "
        "generator, and a run's timing depends on the run alone)")
    waist_reach_m: float = Field(0.15, ge=0, description="how much farther the waist lets a hand reach, for the cheap reach filter")
    screen_valid: int = Field(4, ge=1, description="start/goal nodes validated up front until this many are valid")
    ready_height_m: float = Field(0.15, gt=0, description="ready posture: the hand this far above the highest table top")
    via_lift_m: float = Field(0.15, gt=0, description="via posture: the hand lifted this far above a motion's end")
    limits: bool = Field(True, description="check static joint torques against the effort limits and the grip (CONTRACT "
                         "section 3); off reproduces the paper, which had neither")
    planning_buffer_m: float = Field(
        1e-3, ge=0, description="plan to threshold + this, so small IK residuals never bring a point below the threshold")
    stable_postures: bool = Field(
        True, description="before a key pose is removed for the CoM margin, look for the nearest posture with the hands "
        "in the same place that keeps it (the waist leaning back, the arm re-posed; planner/motion/stable_posture.py)")
    stable_posture_slack_m: float = Field(
        2e-3, ge=0, description="such a posture keeps the planning threshold plus this, so the moves into and out of it keep "
        "the threshold too")

