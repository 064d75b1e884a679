"""Built-in tasks fitted to the robot that runs them.

The built-in scenarios are written for one robot (HRP-5P: hands 0.8 m high, 0.8 m arms). Run with another
humanoid, the same task is placed from that robot's own dimensions, measured in the scenario's stance and
its ready posture:

- horizontal distances (the tables' places and sizes, the object's poses) scale with the arm's reach, about
  the shoulders' midpoint; the tables' near edges stay at least 50 mm ahead of the ready posture's hands;
- heights scale with the reach too, below the shoulders: each table's top, and an object keeps its place on the
  table it rests on;
- the object is scaled with the reach where the robot is smaller (never enlarged), its mass with the cube of
  that scale and at most half of what the weakest arm joint holds at the full reach (``--mass-kg`` overrides);
- the threshold keeps its share of the stance's CoM margin.

The fitted scenario records what was measured and chosen in ``fitted``; a scenario run with its own robot,
or one that is not a built-in's task, is not changed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from planner.robot.model import RobotModel, load_robot
from planner.robot.urdf_geometry import collision_primitives
from schemas.scenario import Scenario

G = 9.81
#: the tables' near edges stay this far ahead of the ready posture's hands (m)
EDGE_CLEARANCE_M = 0.05
#: share of the weakest arm joint's static capacity at full reach the fitted mass may use
PAYLOAD_SHARE = 0.5


@dataclass(frozen=True)
class Dimensions:
    """A robot's figures that place a task, in its stance (world frame)."""

    hand_height_m: float
    reach_m: float
    shoulder_width_m: float
    shoulder_x_m: float
    shoulder_z_m: float
    hands_forward_m: float
    margin_m: float
    payload_kg: float

    def as_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in ("hand_height_m", "reach_m", "shoulder_width_m", "shoulder_z_m",
                                                     "hands_forward_m", "payload_kg")}


def robot_dimensions(robot: RobotModel, stance_ref) -> Dimensions:  # type: ignore[no-untyped-def]
    """Hand height (mean TCP height), reach (the arm's first joint to the TCP along the arm), the shoulders (the
    arms' first joints) and the hands' forward extent in the stance's posture; the stance's CoM margin; the
    payload at full reach."""
    from planner.stability.stances import solve_stance

    stance = solve_stance(robot, stance_ref)
    model, data = robot.pin_model, robot.create_data()
    pin.framesForwardKinematics(model, data, robot.to_pin_q(stance.base_pose, stance.q))
    tcps, shoulders, reaches, payloads = [], [], [], []
    hand_x = []
    for side, arm in robot.spec.arms.items():
        jids = [model.getJointId(n) for n in arm.chain]
        tcp = data.oMf[model.getFrameId(arm.tcp)].translation
        points = [data.oMi[j].translation for j in jids] + [tcp]
        reach = float(sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:])))
        tcps.append(tcp)
        shoulders.append(points[0])
        reaches.append(reach)
        mid = jids[len(jids) // 2]
        hand_links = {f.name for f in model.frames if f.type == pin.FrameType.BODY and mid in model.supports[f.parentJoint]}
        for p in collision_primitives(robot.urdf_path):
            if p.link in hand_links:
                T = data.oMf[model.getFrameId(p.link)]
                hand_x += list((p.local_points() @ T.rotation.T + T.translation)[:, 0])
        hand_x.append(tcp[0])
        # the weakest joint at full reach: its effort over the lever of a load at the TCP plus the reach beyond it
        for k, name in enumerate(arm.chain):
            effort = robot.spec.effort_limits.get(name)
            if effort is None:
                lim = model.effortLimit[model.idx_vs[jids[k]]]
                effort = float(lim) if lim > 0 else math.inf
            lever = sum(np.linalg.norm(b - a) for a, b in zip(points[k:], points[k + 1:])) + 0.1
            payloads.append(effort / (G * lever))
    shoulders_a = np.array(shoulders)
    return Dimensions(
        hand_height_m=float(np.mean([t[2] for t in tcps])), reach_m=float(np.mean(reaches)),
        shoulder_width_m=float(abs(shoulders_a[0, 1] - shoulders_a[1, 1])), shoulder_x_m=float(shoulders_a[:, 0].mean()),
        shoulder_z_m=float(shoulders_a[:, 2].mean()),
        hands_forward_m=float(max(hand_x)), margin_m=float(stance.margin),
        payload_kg=float(PAYLOAD_SHARE * min(payloads)) if payloads else math.inf)


def is_builtin_task(scenario: Scenario) -> bool:
    """Whether ``scenario`` is a built-in scenario's task (its object, poses and tables), whatever robot runs it."""
    from planner.scene.scenarios import builtin_names, load_builtin

    if scenario.name not in builtin_names():
        return False
    own = load_builtin(scenario.name)
    keys = ("object", "start_pose", "goal_pose", "tables", "obstacles")
    return all(getattr(own, k) == getattr(scenario, k) for k in keys)


def fit_to_robot(scenario: Scenario, robot_ref: str) -> Scenario:
    """The built-in ``scenario`` placed for the robot ``robot_ref`` (module docstring); unchanged when it is the
    scenario's own robot or not a built-in's task."""
    from planner.scene.scenarios import load_builtin, parse_scenario

    if not is_builtin_task(scenario):
        return scenario
    own_robot = load_builtin(scenario.name).robot
    if robot_ref == own_robot:
        return scenario
    robot = load_robot(robot_ref)
    if robot.name == own_robot:
        return scenario
    ref = robot_dimensions(load_robot(own_robot), scenario.stance)
    new = robot_dimensions(robot, scenario.stance)
    s = new.reach_m / ref.reach_m
    s_obj = min(1.0, s)

    def height(z: float) -> float:
        return new.shoulder_z_m + (z - ref.shoulder_z_m) * s

    def xy(x: float, y: float) -> tuple[float, float]:
        return new.shoulder_x_m + (x - ref.shoulder_x_m) * s, y * s

    tables = []
    for t in scenario.tables:
        x, y = xy(t.pose[0], t.pose[1])
        size = [t.size[0] * s, t.size[1] * s, t.size[2]]
        top = height(t.pose[2] + t.size[2] / 2)
        z = top - t.size[2] / 2
        if t.pose[2] - t.size[2] / 2 <= 1e-6:  # a table standing on the floor stays on it
            size[2] = max(0.05, top)
            z = size[2] / 2
        tables.append({"name": t.name, "pose": [x, y, z, *t.pose[3:]], "size": size})
    # the near edges clear the ready posture's hands
    near = min(tb["pose"][0] - tb["size"][0] / 2 for tb in tables)
    shift = max(0.0, new.hands_forward_m + EDGE_CLEARANCE_M - near)
    for tb in tables:
        tb["pose"][0] += shift

    def top_under(pose: list[float], tabs: list) -> tuple[int, float]:  # type: ignore[type-arg]
        tops = [(k, tb.pose[2] + tb.size[2] / 2) for k, tb in enumerate(tabs)]
        below = [(k, top) for k, top in tops if top <= pose[2] + 1e-6] or tops
        return max(below, key=lambda kt: kt[1])

    def place(pose: list[float]) -> list[float]:
        k, top = top_under(pose, scenario.tables)
        new_top = tables[k]["pose"][2] + tables[k]["size"][2] / 2
        x, y = xy(pose[0], pose[1])
        return [x + shift, y, new_top + (pose[2] - top) * s_obj, *pose[3:]]

    obj = scenario.object.model_dump()
    if obj.get("size") is not None:
        obj["size"] = [v * s_obj for v in obj["size"]]
    if obj.get("mesh") is not None:
        obj["mesh"]["scale"] = obj["mesh"]["scale"] * s_obj
    if obj.get("com_local") is not None:
        obj["com_local"] = [v * s_obj for v in obj["com_local"]]
    mass = min(obj["mass_kg"] * s ** 3, new.payload_kg)
    obj["mass_kg"] = max(0.1, math.floor(mass * 10) / 10)
    threshold = scenario.threshold_m * (new.margin_m / ref.margin_m) if ref.margin_m > 0 else scenario.threshold_m
    data = scenario.model_dump(by_alias=True)
    data.update(object=obj, tables=tables, start_pose=place(list(scenario.start_pose)),
                goal_pose=place(list(scenario.goal_pose)), threshold_m=round(threshold, 4),
                obstacles=[{"name": o.name, "pose": [*xy(o.pose[0], o.pose[1]), height(o.pose[2]), *o.pose[3:]],
                            "size": [o.size[0] * s, o.size[1] * s, o.size[2]]} for o in scenario.obstacles],
                fitted={"from_robot": own_robot, "robot": robot.name, "scale": s, "object_scale": s_obj,
                        "reference": ref.as_dict(), "dimensions": new.as_dict(), "table_shift_m": shift,
                        "mass_kg": obj["mass_kg"], "threshold_m": round(threshold, 4)})
    from planner.scene.meshes import carry_mesh_source

    return carry_mesh_source(scenario, parse_scenario(data, f"scenario {scenario.name!r} fitted to {robot.name}"))
