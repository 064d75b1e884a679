"""Stances: built-in definitions, and the leg IK that makes them real.

A stance is data (:class:`schemas.stance.StanceDef`): foot placements in the world,
a pelvis height and offset, and optionally a sole the CoM must stand over. Solving
it runs leg IK so that every sole lies flat at its requested place; nothing is
hand-tuned. The four built-ins are derived from the robot spec, so they exist
for every model.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml
from pydantic import ValidationError

from planner.errors import StanceError
from planner.robot.model import RobotModel, UnknownNameError
from planner.stability.robot_com import robot_com
from planner.stability.standing import (
    COM_OVER_TOL_M,
    IK_MAX_ITER,
    IK_POS_TOL_M,
    IK_ROT_TOL_RAD,
    base_orientation,
    bend_knees,
    polygon_centroid,
    sole_box,
    stand,
)
from planner.stability.support_polygon import SupportPolygon, support_polygon
from schemas.stance import SUPPORT_CENTRE, FootPlacement, StanceDef, StanceResult

BUILTIN_STANCES = ("upright", "staggered", "crouched", "one-legged")
__all__ = ["BUILTIN_STANCES", "COM_OVER_TOL_M", "IK_MAX_ITER", "IK_POS_TOL_M", "IK_ROT_TOL_RAD", "Stance", "StanceError", "base_orientation",
           "builtin_stance", "load_stance_file", "polygon_centroid", "resolve_stance", "sole_size", "solve_stance"]


@dataclass(frozen=True)
class Stance:
    """A solved stance: base pose, full posture, feet and support polygon."""

    name: str
    definition: StanceDef
    base_pose: np.ndarray
    q: np.ndarray
    feet: tuple[FootPlacement, ...]
    polygon: SupportPolygon
    robot_com: np.ndarray
    leg_indices: np.ndarray

    @property
    def margin(self) -> float:
        return self.polygon.margin_one(float(self.robot_com[0]), float(self.robot_com[1]))

    def result(self) -> StanceResult:
        return StanceResult(name=self.name, base_pose=self.base_pose.tolist(), feet=list(self.feet))


def _pose(x: float, y: float, z: float) -> list[float]:
    return [x, y, z, 0.0, 0.0, 0.0, 1.0]


def builtin_stance(robot: RobotModel, name: str) -> StanceDef:
    """The contract's built-in stances, scaled to the robot's own foot spacing and height."""
    spec = robot.spec
    fy, h = spec.upright.foot_y_m, spec.upright.pelvis_height_m
    lf, rf = spec.feet["left"].frame, spec.feet["right"].frame
    # As in the paper, a stance moves the feet relative to the robot's own frame. Upright and
    # crouched stand the CoM over the centre of the polygon (crouched lowers the pelvis too);
    # staggered keeps the pelvis where upright has it, so its CoM is not re-centred over the new
    # polygon; one-legged stands the CoM over the right sole.
    if name == "upright":
        return StanceDef(name=name, feet=[FootPlacement(frame=rf, pose=_pose(0, -fy, 0)), FootPlacement(frame=lf, pose=_pose(0, fy, 0))],
                         pelvis_height_m=h, com_over=SUPPORT_CENTRE)
    if name == "staggered":
        # Right sole 50 mm forward, left sole 200 mm back; the pelvis of the upright stance.
        upright = solve_stance(robot, builtin_stance(robot, "upright"))
        return StanceDef(
            name=name,
            feet=[FootPlacement(frame=rf, pose=_pose(0.05, -fy, 0)), FootPlacement(frame=lf, pose=_pose(-0.20, fy, 0))],
            pelvis_height_m=h,
            pelvis_offset=[float(upright.base_pose[0]), float(upright.base_pose[1])],
            com_over=None,
        )
    if name == "crouched":
        return StanceDef(name=name, feet=[FootPlacement(frame=rf, pose=_pose(0, -fy, 0)), FootPlacement(frame=lf, pose=_pose(0, fy, 0))],
                         pelvis_height_m=h - 0.15, com_over=SUPPORT_CENTRE)
    if name == "one-legged":
        return StanceDef(
            name=name,
            feet=[FootPlacement(frame=rf, pose=_pose(0, -fy, 0)), FootPlacement(frame=lf, in_contact=False, pose=_pose(0, fy, 0.05))],
            pelvis_height_m=h,
            pelvis_offset=[0.0, -fy],
            com_over=rf,
        )
    raise UnknownNameError(f"unknown stance {name!r}; built-in stances: {', '.join(BUILTIN_STANCES)}")


def load_stance_file(path: str | Path) -> StanceDef:
    """A user stance from YAML/JSON with the fields of :class:`StanceDef`."""
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise StanceError(f"cannot read stance file {path}: {exc}") from exc
    try:
        return StanceDef.model_validate(data)
    except ValidationError as exc:
        raise StanceError(f"stance file {path} is invalid: {exc}") from exc


def resolve_stance(robot: RobotModel, stance: str | StanceDef) -> StanceDef:
    if isinstance(stance, StanceDef):
        return stance
    if stance.endswith((".yaml", ".yml", ".json")) and Path(stance).is_file():
        return load_stance_file(stance)
    return builtin_stance(robot, stance)


def _leg_for_frame(robot: RobotModel, frame: str) -> list[str]:
    for foot in robot.spec.feet.values():
        if foot.frame == frame:
            return foot.chain
    valid = [f.frame for f in robot.spec.feet.values()]
    raise UnknownNameError(f"robot {robot.name!r} has no sole frame {frame!r}; valid sole frames: {', '.join(valid)}")


def solve_stance(robot: RobotModel, stance: str | StanceDef) -> Stance:
    """Leg IK for every foot; for ``com_over`` stances the pelvis shifts until the CoM is above that sole."""
    sdef = resolve_stance(robot, stance)
    data = robot.create_data()
    height = sdef.pelvis_height_m if sdef.pelvis_height_m is not None else robot.spec.upright.pelvis_height_m
    offset = np.array(sdef.pelvis_offset, dtype=float)
    q = robot.default_q()
    leg_idx: list[int] = []
    for foot in sdef.feet:
        leg_idx += bend_knees(robot, q, _leg_for_frame(robot, foot.frame)).tolist()
    targets = [(_leg_for_frame(robot, f.frame), f.frame, pin.XYZQUATToSE3(np.array(f.pose))) for f in sdef.feet]
    soles = []
    for foot in sdef.feet:
        M = pin.XYZQUATToSE3(np.array(foot.pose))
        length, width = sole_size(robot, foot.frame)
        soles.append((M.rotation, M.translation, length, width, foot.in_contact))
    polygon = SupportPolygon(support_polygon(soles))
    goal = None
    if sdef.com_over is not None:
        if sdef.com_over == SUPPORT_CENTRE:
            goal = polygon_centroid(polygon.vertices)
        else:
            goal = next(np.array(f.pose[:2]) for f in sdef.feet if f.frame == sdef.com_over)
    base = stand(robot, data, q, targets, height, offset, goal, sdef.name, str(sdef.com_over))
    com = robot_com(robot, data, base, q)
    return Stance(
        name=sdef.name, definition=sdef, base_pose=base, q=q, feet=tuple(sdef.feet), polygon=polygon,
        robot_com=com, leg_indices=np.array(sorted(set(leg_idx)), dtype=int),
    )


def sole_size(robot: RobotModel, frame: str) -> tuple[float, float]:
    """(length, width) of a sole: the x/y sizes of the collision box on the sole frame."""
    _leg_for_frame(robot, frame)
    return sole_box(robot, frame)
