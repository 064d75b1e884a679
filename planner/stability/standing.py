"""Standing the robot on its feet: flat soles by leg IK, and the pelvis moved until the CoM stands over a point.

The stance solver (:mod:`planner.stability.stances`) stands every stance with these, and the robot loader
stands the derived ready posture with them (its legs keep the CoM over the centre of the upright stance's
feet). That is why this module imports nothing from :mod:`planner.robot`: ``robot`` is a
:class:`planner.robot.model.RobotModel` passed in by the caller, so the loader can use it while it builds the
model without an import cycle, and the CoM is still computed here, in planner/stability.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any

import numpy as np
import pinocchio as pin

from planner.errors import StanceError
from planner.stability.support_polygon import support_polygon

#: IK convergence: soles within 0.05 mm and 1e-4 rad of their targets.
IK_POS_TOL_M = 5e-5
IK_ROT_TOL_RAD = 1e-4
IK_MAX_ITER = 200
#: The CoM's ground projection within 0.1 mm of its goal.
COM_OVER_TOL_M = 1e-4
#: A foot's target is reached when its residual is below 1 mm.
REACH_TOL_M = 1e-3
#: Leg IK starts from a bent knee (hip pitch, knee, ankle pitch as the third to fifth joints of a six-joint leg).
BENT_KNEE = np.array([0, 0, -0.4, 0.8, -0.4, 0])

#: (leg chain, sole frame, the sole's world target)
FootTarget = tuple[list[str], str, pin.SE3]


def solve_leg(robot: Any, data: pin.Data, base_pose: np.ndarray, q: np.ndarray, chain: list[str], frame: str,
              target: pin.SE3) -> float:
    """Damped least-squares leg IK in place on ``q``; returns the remaining position error (m)."""
    model = robot.pin_model
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


def bend_knees(robot: Any, q: np.ndarray, chain: list[str]) -> np.ndarray:
    """Set the leg's joints in ``q`` to the bent-knee start (so the solver never sits on the straight-leg
    singularity; a knee that bends the other way, its flexion negative as iCub's, bends the start the other
    way); returns the leg's joint indices."""
    idx = robot.joint_indices(chain)
    bent = BENT_KNEE
    if robot.upper[idx[3]] < 0.8 <= -robot.lower[idx[3]]:
        bent = -bent
    q[idx] = np.clip(bent, robot.lower[idx], robot.upper[idx])
    return idx


def base_orientation(robot: Any) -> tuple[float, float, float, float]:
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


def stand(robot: Any, data: pin.Data, q: np.ndarray, targets: list[FootTarget], height: float,
          offset: np.ndarray, com_goal: np.ndarray | None, name: str, goal_name: str = "its goal") -> np.ndarray:
    """Stand ``q`` (legs changed in place) with every sole flat at its target and the pelvis at ``height``;
    with a ``com_goal`` (x, y), the pelvis moves sideways and forward until the CoM's ground projection is
    within COM_OVER_TOL_M of it. Returns the base pose; raises :class:`StanceError` when a foot cannot reach
    its target or the CoM cannot be brought over the goal."""
    facing = base_orientation(robot)

    def solve_at(off: np.ndarray) -> np.ndarray:
        base = np.array([off[0], off[1], height, *facing])
        for chain, frame, target in targets:
            residual = solve_leg(robot, data, base, q, chain, frame, target)
            if residual > REACH_TOL_M:
                raise StanceError(
                    f"stance {name!r}: foot {frame} cannot reach its placement; it stays "
                    f"{residual * 1000:.1f} mm short (pelvis at height {height:.3f} m, offset {off.round(4).tolist()})"
                )
        return base

    offset = np.array(offset, dtype=float)
    base = solve_at(offset)
    if com_goal is not None:
        for _ in range(50):
            com = pin.centerOfMass(robot.pin_model, data, robot.to_pin_q(base, q), False)
            delta = com_goal - com[:2]
            if np.linalg.norm(delta) < COM_OVER_TOL_M:
                break
            offset = offset + delta
            base = solve_at(offset)
        else:
            raise StanceError(f"stance {name!r}: could not bring the CoM above {goal_name}")
    return base


def polygon_centroid(vertices: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon (CCW vertices)."""
    x, y = vertices[:, 0], vertices[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area)


def sole_box(robot: Any, frame: str) -> tuple[float, float]:
    """(length, width) of a sole: the x/y sizes of the collision box on the sole frame's link."""
    root = ET.parse(robot.urdf_path).getroot()
    for link in root.iter("link"):
        if link.attrib["name"] == frame:
            box = link.find("collision/geometry/box")
            if box is None:
                break
            sx, sy, _ = (float(v) for v in box.attrib["size"].split())
            return sx, sy
    raise ValueError(f"robot {robot.name!r}: sole frame {frame} carries no collision box")


def centred_legs(robot: Any, q: np.ndarray) -> np.ndarray:
    """``q`` with the legs' joints changed so that, the pelvis upright at the spec's pelvis height, both soles
    lie flat at the upright stance's placements relative to each other (``foot_y_m`` either side, level, facing
    forward) and the CoM stands over the centre between them, the centre of their support polygon (the hip,
    knee and ankle pitch joints lean the body over the feet, the rolls shift it sideways; the arms, waist and
    neck keep their values). Raises :class:`StanceError` when the legs cannot do it within their limits."""
    spec = robot.spec
    out = np.array(q, dtype=float)
    fy = spec.upright.foot_y_m
    targets: list[FootTarget] = []
    soles = []
    for side, y in (("right", -fy), ("left", fy)):
        foot = spec.feet[side]
        bend_knees(robot, out, foot.chain)
        placement = pin.SE3(np.eye(3), np.array([0.0, y, 0.0]))
        targets.append((foot.chain, foot.frame, placement))
        soles.append((placement.rotation, placement.translation, *sole_box(robot, foot.frame), True))
    centre = polygon_centroid(support_polygon(soles))
    stand(robot, robot.create_data(), out, targets, spec.upright.pelvis_height_m, np.zeros(2), centre,
          "ready posture", "the centre of the support polygon")
    return out


def posture_com_offset(robot: Any, q: np.ndarray) -> tuple[np.ndarray, float]:
    """Where the posture ``q`` stands its CoM: (CoM minus the centre of the support polygon of both soles, x and y
    in m; the largest tilt of a sole from flat, rad), with the pelvis upright at the spec's pelvis height and the
    soles where ``q`` puts them (the ready posture's own balance, as ``robot check`` prints it)."""
    base = np.array([0.0, 0.0, robot.spec.upright.pelvis_height_m, *base_orientation(robot)])
    model, data = robot.pin_model, robot.create_data()
    q_pin = robot.to_pin_q(base, q)
    pin.framesForwardKinematics(model, data, q_pin)
    soles, tilt = [], 0.0
    for foot in robot.spec.feet.values():
        M = data.oMf[robot.frame_id(foot.frame)]
        tilt = max(tilt, float(np.arccos(np.clip(M.rotation[2, 2], -1.0, 1.0))))
        soles.append((M.rotation, M.translation, *sole_box(robot, foot.frame), True))
    centre = polygon_centroid(support_polygon(soles))
    com = pin.centerOfMass(model, data, q_pin, False)
    return np.asarray(com[:2]) - centre, tilt
