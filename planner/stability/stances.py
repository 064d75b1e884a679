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
from planner.stability.support_polygon import SupportPolygon, support_polygon
from schemas.stance import SUPPORT_CENTRE, FootPlacement, StanceDef, StanceResult

BUILTIN_STANCES = ("upright", "staggered", "crouched", "one-legged")
#: IK convergence: soles within 0.05 mm and 1e-4 rad of their targets.
IK_POS_TOL_M = 5e-5
IK_ROT_TOL_RAD = 1e-4
IK_MAX_ITER = 200
#: One-legged: the CoM ground projection within 0.1 mm of the sole centre.
COM_OVER_TOL_M = 1e-4


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


def _solve_leg(robot: RobotModel, data: pin.Data, base_pose: np.ndarray, q: np.ndarray, frame: str, target: pin.SE3) -> float:
    """Damped least-squares leg IK in place on ``q``; returns the remaining position error (m)."""
    model = robot.pin_model
    chain = _leg_for_frame(robot, frame)
    idx = robot.joint_indices(chain)
    vcols = [model.idx_vs[model.getJointId(n)] for n in chain]
    fid = robot.frame_id(frame)
    lam2 = 1e-6
    err = np.zeros(6)
    for _ in range(IK_MAX_ITER):
        qp = robot.to_pin_q(base_pose, q)
        pin.forwardKinematics(model, data, qp)
        current = pin.updateFramePlacement(model, data, fid)
        err = pin.log6(current.actInv(target)).vector
        if np.linalg.norm(err[:3]) < IK_POS_TOL_M and np.linalg.norm(err[3:]) < IK_ROT_TOL_RAD:
            break
        J = pin.computeFrameJacobian(model, data, qp, fid, pin.LOCAL)[:, vcols]
        dq = J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(6), err)
        q[idx] = np.clip(q[idx] + dq, robot.lower[idx], robot.upper[idx])
    return float(np.linalg.norm(err[:3]))


def solve_stance(robot: RobotModel, stance: str | StanceDef) -> Stance:
    """Leg IK for every foot; for ``com_over`` stances the pelvis shifts until the CoM is above that sole."""
    sdef = resolve_stance(robot, stance)
    data = robot.create_data()
    height = sdef.pelvis_height_m if sdef.pelvis_height_m is not None else robot.spec.upright.pelvis_height_m
    offset = np.array(sdef.pelvis_offset, dtype=float)
    q = robot.default_q()
    leg_idx: list[int] = []
    for foot in sdef.feet:
        chain = _leg_for_frame(robot, foot.frame)
        idx = robot.joint_indices(chain)
        leg_idx += idx.tolist()
        # Start from a bent knee so the solver never sits on the straight-leg singularity; a knee that bends
        # the other way (its flexion negative, as iCub's) bends the start the other way.
        bent = np.array([0, 0, -0.4, 0.8, -0.4, 0])
        if robot.upper[idx[3]] < 0.8 <= -robot.lower[idx[3]]:
            bent = -bent
        q[idx] = np.clip(bent, robot.lower[idx], robot.upper[idx])
    targets = [(f.frame, pin.XYZQUATToSE3(np.array(f.pose))) for f in sdef.feet]

    facing = base_orientation(robot)

    def solve_at(off: np.ndarray) -> np.ndarray:
        base = np.array([off[0], off[1], height, *facing])
        for frame, target in targets:
            residual = _solve_leg(robot, data, base, q, frame, target)
            if residual > 1e-3:
                raise StanceError(
                    f"stance {sdef.name!r}: foot {frame} cannot reach its placement; it stays "
                    f"{residual * 1000:.1f} mm short (pelvis at height {height:.3f} m, offset {off.round(4).tolist()})"
                )
        return base

    base = solve_at(offset)
    soles = []
    for foot in sdef.feet:
        M = pin.XYZQUATToSE3(np.array(foot.pose))
        length, width = sole_size(robot, foot.frame)
        soles.append((M.rotation, M.translation, length, width, foot.in_contact))
    polygon = SupportPolygon(support_polygon(soles))
    if sdef.com_over is not None:
        if sdef.com_over == SUPPORT_CENTRE:
            goal = polygon_centroid(polygon.vertices)
        else:
            goal = next(np.array(f.pose[:2]) for f in sdef.feet if f.frame == sdef.com_over)
        for _ in range(50):
            com = robot_com(robot, data, base, q)
            delta = goal - com[:2]
            if np.linalg.norm(delta) < COM_OVER_TOL_M:
                break
            offset = offset + delta
            base = solve_at(offset)
        else:
            raise StanceError(f"stance {sdef.name!r}: could not bring the CoM above {sdef.com_over}")
    com = robot_com(robot, data, base, q)
    return Stance(
        name=sdef.name, definition=sdef, base_pose=base, q=q, feet=tuple(sdef.feet), polygon=polygon,
        robot_com=com, leg_indices=np.array(sorted(set(leg_idx)), dtype=int),
    )


def base_orientation(robot: RobotModel) -> tuple[float, float, float, float]:
    """The root's world orientation (quaternion x, y, z, w) that makes the robot face the world's +x: a yaw
    turning the soles' x axes (their forward, with every joint at zero, so feet a default posture turns out do
    not turn the robot) onto +x. The identity for a robot whose root frame faces forward (x ahead, as most URDFs
    have it); a half turn for one whose root faces backward (iCub's)."""

    def build() -> tuple[float, float, float, float]:
        data = robot.create_data()
        neutral = np.clip(np.zeros(robot.nq), robot.lower, robot.upper)
        pin.framesForwardKinematics(robot.pin_model, data, robot.to_pin_q(np.array([0, 0, 0, 0, 0, 0, 1.0]), neutral))
        ahead = sum(data.oMf[robot.frame_id(robot.spec.feet[side].frame)].rotation[:2, 0] for side in ("left", "right"))
        yaw = float(np.arctan2(ahead[1], ahead[0]))
        if abs(yaw) < 1e-9:
            return (0.0, 0.0, 0.0, 1.0)
        return (0.0, 0.0, float(np.sin(-yaw / 2)), float(np.cos(-yaw / 2)))

    return robot.derived(("base_orientation",), build)


def polygon_centroid(vertices: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon (CCW vertices)."""
    x, y = vertices[:, 0], vertices[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area)


def sole_size(robot: RobotModel, frame: str) -> tuple[float, float]:
    """(length, width) of a sole: the x/y sizes of the collision box on the sole frame."""
    import xml.etree.ElementTree as ET

    _leg_for_frame(robot, frame)
    root = ET.parse(robot.urdf_path).getroot()
    for link in root.iter("link"):
        if link.attrib["name"] == frame:
            box = link.find("collision/geometry/box")
            if box is None:
                break
            sx, sy, _ = (float(v) for v in box.attrib["size"].split())
            return sx, sy
    raise ValueError(f"robot {robot.name!r}: sole frame {frame} carries no collision box")
