"""Recovery: a plan from the robot's measured joint state back to its stance posture (the ``recover`` job).

After an abort the robot stands where the stop caught it, mid-motion. A recover
job plans from that measured state (``state/joints``: joint names, q, the stance
the controller stands in and what its hands hold) back to the stance's own
posture, and returns an ordinary plan document (`regrasp.plan/1`) that is
approved, gated and dispatched like any plan.

The margin rule: the CoM margin stays at or above the threshold where it can.
Where the measured state is already below the threshold, the floor is the
margin the motion starts with: the recovery never lowers it (the gate applies
the same floor to a recover job's plan). The straight joint-space line is tried
first; when it dips below the floor (or collides), the T-RRT planner searches a
path whose every state keeps the floor. The path is then timed rest to rest
within the joint limits, slowed where the cart-table ZMP would leave the polygon
(``planner.motion.timing``), and checked densely against the floor.

What the hands hold stays held (jaws unchanged); its mass counts in the system
CoM, from the object the request carries (mass, CoM and pose at the measured state,
which the service takes from the aborted plan); without one a recovery while
holding is infeasible.
Collisions are checked for the robot's own bodies; the controller does not report
the tables and obstacles around it.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.errors import InputError
from planner.motion.interpolation import edge_states
from planner.motion.timing import MARGIN_TOLERANCE_M, TimingSettings, time_path
from planner.motion.trrt import TrrtSettings, plan_motion
from planner.regrasp.plan_assembly import MotionPiece, assemble, trajectory_points
from planner.stability.evaluator import HoldSpec, StateEvaluator
from planner.termination import Termination, never
from planner.transforms import pose7_to_matrix
from schemas.plan import PLAN_SCHEMA

#: Default CoM margin threshold of a recovery (m), the scenarios' default.
DEFAULT_THRESHOLD_M = 0.06
#: A measured joint value this far outside its URDF limit is refused (rad or m); smaller excursions are clipped.
LIMIT_SLACK = 1e-6


class RecoverySettings(BaseModel):
    """How a recovery is planned."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    threshold_m: float = Field(DEFAULT_THRESHOLD_M, ge=0, le=0.5, description="CoM margin kept where it can be")
    seed: int = Field(0, ge=0, description="seed of the T-RRT search (a numpy Generator per job)")
    line_resolution_rad: float = Field(0.01, gt=0, description="largest per-joint change between checked states")
    trrt: TrrtSettings = Field(default_factory=lambda: TrrtSettings(max_iterations=400))
    timing: TimingSettings = Field(default_factory=TimingSettings)
    check_self_collision: bool = True


class RecoveryError(InputError):
    """The measured state cannot be recovered from (it names why); the job ends infeasible with the code."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


def _measured_q(robot: Any, joint_names: list[str], q: list[float]) -> np.ndarray:
    names = list(joint_names)
    if len(names) != len(q):
        raise RecoveryError("BAD_STATE", f"the measured state has {len(names)} joint names for {len(q)} values")
    missing = sorted(set(robot.joint_names) - set(names))
    unknown = sorted(set(names) - set(robot.joint_names))
    if missing or unknown:
        raise RecoveryError("BAD_STATE", f"the measured joints differ from {robot.name}'s: missing {missing}, "
                                         f"unknown {unknown}")
    by_name = dict(zip(names, q))
    out = np.array([float(by_name[n]) for n in robot.joint_names])
    if not np.all(np.isfinite(out)):
        raise RecoveryError("BAD_STATE", "the measured joint state is not finite")
    over = (out < robot.lower - LIMIT_SLACK) | (out > robot.upper + LIMIT_SLACK)
    if over.any():
        j = int(np.flatnonzero(over)[0])
        raise RecoveryError("BAD_STATE", f"measured {robot.joint_names[j]} = {out[j]:.4f} is outside its limits "
                                         f"[{robot.lower[j]:.4f}, {robot.upper[j]:.4f}]")
    return np.clip(out, robot.lower, robot.upper)


def _jaw_indices(robot: Any, holding: str) -> list[int]:
    """Columns of the jaw joints of the holding hands (kept as they are: a held object stays held)."""
    sides = {"none": (), "left": ("left",), "right": ("right",), "both": ("left", "right")}[holding]
    grippers = [robot.spec.arms[side].gripper for side in sides]
    return [robot.joint_index(g.joint) for g in grippers if g is not None]  # a rigid hand has no jaw


def plan_recovery(robot_name: str, stance_name: str, joint_names: list[str], q: list[float], *, holding: str = "none",
                  obj: dict[str, Any] | None = None, settings: RecoverySettings | None = None,
                  should_stop: Callable[[], bool] | None = None) -> dict[str, Any]:
    """The recovery plan document from a measured state, or an infeasible one with its failure code."""
    from planner.robot.model import load_robot
    from planner.scene.collision import CollisionWorld
    from planner.stability.stances import solve_stance

    s = settings or RecoverySettings()
    t0 = time.perf_counter()
    robot = load_robot(robot_name)
    stance = solve_stance(robot, stance_name)
    mass = float(obj["mass_kg"]) if obj and holding != "none" else 0.0
    com_local = np.asarray(obj["com_local"], float) if obj and holding != "none" else np.zeros(3)
    evaluator = StateEvaluator(robot, stance, s.threshold_m, mass, com_local)
    object_pose = np.asarray(obj["pose"], float) if obj and obj.get("pose") is not None else None
    base = {"robot": {"name": robot.name, "urdf_sha256": robot.urdf_sha256, "joint_names": list(robot.joint_names)},
            "stance": stance.result().model_dump(), "support_polygon": stance.polygon.vertices.tolist(),
            "threshold_m": s.threshold_m, "hands": "right-right", "dt_s": s.timing.dt_s}

    def infeasible(code: str, message: str) -> dict[str, Any]:
        return {"schema": PLAN_SCHEMA, "status": "infeasible", "failure": {"code": code, "message": message, "counts": {}},
                **base, "scenario": {"name": "recover"}, "object": None, "trajectory": [], "segments": [],
                "min_margin_m": None, "alternatives": [], "stats": {"time_s": time.perf_counter() - t0}}

    try:
        q0 = _measured_q(robot, joint_names, q)
    except RecoveryError as exc:
        return infeasible(exc.code, exc.message)
    if holding != "none" and (object_pose is None or obj is None):
        return infeasible("HOLDING_UNKNOWN_OBJECT", f"the controller reports the hands hold an object ({holding}) but "
                                                    "the request does not give it (mass_kg, com_local, pose)")
    hold = None
    if holding != "none":
        side = "left" if holding == "both" else holding
        T_world_tcp = evaluator.tcp_pose(q0, side)
        hold = HoldSpec(holding, np.linalg.inv(pose7_to_matrix(object_pose)) @ T_world_tcp)  # type: ignore[arg-type]
    goal = stance.q.copy()
    jaws = _jaw_indices(robot, holding)
    goal[jaws] = q0[jaws]

    start_margin = float(evaluator.evaluate_one(q0, hold).margin)
    floor = min(s.threshold_m, start_margin)
    goal_margin = float(evaluator.evaluate_one(goal, hold).margin)
    if goal_margin < floor - MARGIN_TOLERANCE_M:
        return infeasible("COM_MARGIN", f"the stance posture's margin ({goal_margin * 1000:.1f} mm) is below the floor "
                                        f"{floor * 1000:.1f} mm with what the hands hold")
    world = None
    if s.check_self_collision:
        world = CollisionWorld(robot, reference_postures=[(stance.base_pose, stance.q)])

    def valid(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        batch = evaluator.evaluate(Q, hold, threshold_m=0.0)
        ok = batch.margin >= floor - MARGIN_TOLERANCE_M
        if world is not None and ok.any():
            ok[ok] = ~world.check_batch(stance.base_pose, Q[ok]).collides
        return ok, batch.margin

    stats: dict[str, Any] = {"recovery": {"start_margin_m": start_margin, "floor_m": floor, "goal_margin_m": goal_margin,
                                          "holding": holding}}
    line = edge_states(q0, goal, s.line_resolution_rad)
    ok, _ = valid(np.vstack([q0[None], line, goal[None]]))
    if ok.all():
        waypoints = np.vstack([q0, goal])
        stats["recovery"]["path"] = "straight line"
    else:
        moving = np.flatnonzero(np.abs(goal - q0) > 1e-12)
        active = np.setdiff1d(np.arange(robot.nq), np.concatenate([stance.leg_indices, jaws]).astype(int))
        active = np.union1d(active, moving)
        res = plan_motion(q0, goal, active, valid, robot.lower, robot.upper, np.random.default_rng(s.seed), s.trrt,
                          Termination(s.trrt.max_iterations, canceled=should_stop or never))
        stats["recovery"]["path"] = f"T-RRT ({res.status})"
        stats["recovery"]["trrt"] = res.stats
        if res.path is None:
            return infeasible("NO_PATH", f"no path keeps the margin floor {floor * 1000:.1f} mm: {res.reason}")
        waypoints = np.asarray(res.path)
    timed = time_path(waypoints, robot, evaluator, hold, s.timing, threshold_m=floor)
    if not timed.ok:
        return infeasible("TIMING", f"the recovery cannot be timed within the limits: {timed.reason}")
    start_pose = object_pose if object_pose is not None else np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0])
    piece = MotionPiece(kind="transit" if holding == "none" else "transfer",
                        hand="none" if holding == "none" else holding, waypoints=timed.Q, holding=holding, hold=hold)
    traj = assemble([piece], evaluator, s.timing.dt_s, pose7_to_matrix(start_pose))
    points = trajectory_points(traj)
    pose_first, pose_last = points[0]["object_pose"], points[-1]["object_pose"]
    stats["time_s"] = time.perf_counter() - t0
    stats["recovery"]["duration_s"] = float(traj.t[-1])
    return {
        "schema": PLAN_SCHEMA, "status": "solved", "failure": None, **base,
        "scenario": {"name": "recover", "robot": robot.name, "stance": stance.name, "threshold_m": s.threshold_m},
        "object": {"name": (obj or {}).get("name", "held object" if holding != "none" else "none"), "mass_kg": mass,
                   "com_local": com_local.tolist(), "start_pose": pose_first, "goal_pose": pose_last},
        "trajectory": points, "segments": traj.segments, "min_margin_m": float(traj.margin.min()),
        "alternatives": [], "stats": stats,
    }


def recover_job(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    """The service's recover job: the measured state the API stored with the request -> a plan document."""
    from planner.errors import Canceled

    measured = request["measured"]
    settings = RecoverySettings(threshold_m=request.get("threshold_m", DEFAULT_THRESHOLD_M),
                                seed=int(request.get("seed") or 0))
    ctx.progress(0.1, "planning the recovery to the stance posture")

    def stop() -> bool:
        if ctx.cancelled():
            raise Canceled("recovery canceled")
        return False

    doc = plan_recovery(request["model"], measured.get("stance") or "upright", measured["joint_names"], measured["q"],
                        holding=measured.get("holding") or "none", obj=request.get("object"), settings=settings,
                        should_stop=stop)
    ctx.progress(1.0, "recovery planned" if doc["status"] == "solved" else "no recovery found")
    return doc
