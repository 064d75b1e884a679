"""A hand's collision shapes in its TCP frame, at any jaw opening (grasp planning, handover poses
and the collision checker's finger rules use them). Derived once per robot model.

A rigid hand (no jaw) has one shape set and no fingers: its opening is always 0."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from planner.robot.model import RobotModel
from planner.robot.spec import Side
from planner.robot.urdf_geometry import collision_primitives
from planner.scene.bodies import Body, fcl_geometry, half_extents
from planner.transforms import inverse


@dataclass(frozen=True)
class HandShape:
    link: str
    kind: str
    dims: tuple[float, ...]
    T_tcp_shape0: np.ndarray  # pose in the TCP frame with the jaw at 0
    is_finger: bool


@dataclass(frozen=True)
class HandGeometry:
    """The hand's collision primitives in its TCP frame, fingers as a function of the jaw value.

    Read from the URDF (link primitives) and pinocchio (link placements), so nothing here
    is specific to one robot: the hand is every link rigidly attached to the TCP's parent
    joint plus the links moved by the gripper joint and its mimic joints (sliding or
    rotating: the placements come from forward kinematics at the requested jaw value).
    """

    side: str
    shapes: tuple[HandShape, ...]
    max_opening_m: float
    opening_per_unit: float
    robot: RobotModel = field(repr=False, compare=False)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)
    #: the jaw joint's value when closed (opening 0)
    closed_value: float = 0.0

    @property
    def has_jaw(self) -> bool:
        """False for a rigid hand (its opening is 0): nothing opens, a held object attaches at the TCP."""
        return self.max_opening_m > 0.0

    def jaw_value(self, opening_m: float) -> float:
        """The jaw joint's value for an opening (m); 0 for a rigid hand, which has no jaw joint."""
        if not self.has_jaw:
            return 0.0
        return float(opening_m) / self.opening_per_unit + self.closed_value

    def at_opening(self, opening_m: float) -> list[tuple[str, str, tuple[float, ...], np.ndarray]]:
        """(link, kind, dims, T_tcp_shape) of every shape with the jaw opened to ``opening_m``."""
        value = round(self.jaw_value(opening_m), 12)
        poses = self._cache.get(value)
        if poses is None:
            poses = _hand_shape_poses(self.robot, self.side, value)[1]
            self._cache[value] = poses
        return [(s.link, s.kind, s.dims, T.copy()) for s, T in zip(self.shapes, poses)]

    def signature(self) -> bytes:
        """Bytes that identify the geometry (cache keys): shapes at the jaw closed and fully open."""
        parts = [f"{self.max_opening_m:.9f}/{self.opening_per_unit:.9f}".encode()]
        if not self.has_jaw:
            parts.append(b"rigid")
        if self.closed_value != 0.0:
            parts.append(f"{self.closed_value:.9f}".encode())
        full = [T for *_rest, T in self.at_opening(self.max_opening_m)]
        for s, T_open in zip(self.shapes, full):
            # "+ 0.0" turns -0.0 into 0.0, so mirrored hands with equal geometry share a signature
            parts.append(f"{s.kind}{(np.round(s.dims, 9) + 0.0).tolist()}{s.is_finger}".encode())
            parts.append((np.round(s.T_tcp_shape0, 9) + 0.0).tobytes())
            parts.append((np.round(T_open, 9) + 0.0).tobytes())
        return b"|".join(parts)


def hand_links(robot: RobotModel, side: Side) -> tuple[set[int], set[int]]:
    """(pinocchio joint ids that carry the hand, those that carry fingers)."""
    model = robot.pin_model
    arm = robot.spec.arms[side]
    tcp_joint = int(model.frames[robot.frame_id(arm.tcp)].parentJoint)
    if arm.gripper is None:
        return {tcp_joint}, set()
    finger_joints = {int(model.getJointId(arm.gripper.joint))}
    for mimic, (master, _k, _b) in robot.mimic.items():
        if master == arm.gripper.joint:
            finger_joints.add(int(model.getJointId(mimic)))
    return {tcp_joint}, finger_joints


def contact_joints(robot: RobotModel, side: Side) -> set[int]:
    """Pinocchio joint ids whose bodies may touch an object the hand grasps or holds: a jaw's fingers; a rigid
    hand touches it with itself."""
    palm, fingers = hand_links(robot, side)
    return fingers if robot.spec.arms[side].gripper is not None else palm


def hand_geometry(robot: RobotModel, side: Side) -> HandGeometry:
    """The hand of ``side`` in its TCP frame (see :class:`HandGeometry`), derived once per robot model."""

    def build() -> HandGeometry:
        shapes, _poses = _hand_shape_poses(robot, side, 0.0)
        if not shapes:
            raise ValueError(f"robot {robot.name!r}: the {side} hand has no collision primitives")
        g = robot.spec.arms[side].gripper
        if g is None:
            return HandGeometry(side, tuple(shapes), 0.0, 1.0, robot)
        return HandGeometry(side, tuple(shapes), g.max_opening_m, g.opening_per_unit, robot, closed_value=g.closed_value)

    return robot.derived(("hand_geometry", side), build)


def _hand_setup(robot: RobotModel, side: Side) -> tuple:
    """What FK of one hand needs, derived once per robot model: frame ids, the hand's primitives, a posture."""

    def build() -> tuple:
        model = robot.pin_model
        arm = robot.spec.arms[side]
        palm_joints, finger_joints = hand_links(robot, side)
        link_joint = {f.name: int(f.parentJoint) for f in model.frames if f.type == pin.FrameType.BODY}
        prims = []
        for prim in collision_primitives(robot.urdf_path):
            jid = link_joint.get(prim.link)
            if jid is not None and jid in palm_joints | finger_joints:
                prims.append((prim, int(model.getFrameId(prim.link)), jid in finger_joints))
        jaw = None if arm.gripper is None else robot.joint_index(arm.gripper.joint)
        return robot.frame_id(arm.tcp), jaw, tuple(prims), robot.default_q()

    return robot.derived(("hand_setup", side), build)


def _hand_shape_poses(robot: RobotModel, side: Side, jaw_value: float) -> tuple[list[HandShape], list[np.ndarray]]:
    """The hand's shapes and their poses in the TCP frame at one jaw value (pinocchio FK)."""
    model = robot.pin_model
    tcp_fid, jaw, prims, q0 = _hand_setup(robot, side)
    data = robot.create_data()
    q = q0.copy()
    if jaw is not None:
        q[jaw] = jaw_value
    pin.forwardKinematics(model, data, robot.to_pin_q(np.array([0, 0, 0, 0, 0, 0, 1.0]), q))
    T_tcp_w = inverse(pin.updateFramePlacement(model, data, tcp_fid).homogeneous)
    shapes, poses = [], []
    for prim, fid, is_finger in prims:
        T = T_tcp_w @ pin.updateFramePlacement(model, data, fid).homogeneous @ prim.origin
        shapes.append(HandShape(prim.link, prim.kind, tuple(prim.dims), T, is_finger))
        poses.append(T)
    return shapes, poses


def hand_bodies(hand: HandGeometry, opening_m: float, include_fingers: bool = True) -> list[Body]:
    """The hand's shapes as bodies whose parent frame is the TCP."""
    out = []
    for (link, kind, dims, T), s in zip(hand.at_opening(opening_m), hand.shapes):
        if s.is_finger and not include_fingers:
            continue
        out.append(Body(link, "robot", kind, dims, T, half_extents(kind, dims), np.zeros(3), link=link,
                         geometry=fcl_geometry(kind, dims)))
    return out


