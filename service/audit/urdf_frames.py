"""Link transforms of a URDF at a joint configuration, for Foxglove's /tf.

Foxglove's 3D panel draws each URDF link in the frame named after it and places
the frames from the transform tree; it adds every joint at its zero position
itself, so to show the robot *moving* the audit file publishes, per sample, the
transform of every non-fixed joint (parent link -> child link, origin then joint
motion) and the floating base (``world`` -> root link).

This is a small standalone parser (xml.etree + numpy): the audit code stays
independent of the planner and of pinocchio, and works for any robot URDF.
Mimic joints follow their master through ``multiplier`` and ``offset``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Mapping, Sequence

#: The fixed frame of every audit file (the contract's world frame).
WORLD_FRAME = "world"


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    kind: str  # revolute, continuous, prismatic, fixed, ...
    parent: str
    child: str
    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]  # x, y, z, w of the origin rpy
    axis: tuple[float, float, float]
    mimic: tuple[str, float, float] | None  # master, multiplier, offset


@dataclass(frozen=True)
class UrdfTree:
    root: str
    joints: tuple[UrdfJoint, ...]

    @property
    def moving(self) -> tuple[UrdfJoint, ...]:
        return tuple(j for j in self.joints if j.kind != "fixed")


def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    if not text:
        return default
    values = tuple(float(v) for v in text.split())
    if len(values) != len(default):
        raise ValueError(f"expected {len(default)} numbers, got {text!r}")
    return values


def rpy_to_quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """URDF fixed-axis roll/pitch/yaw to a unit quaternion (x, y, z, w)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def quat_mul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def quat_rotate(q: Sequence[float], v: Sequence[float]) -> tuple[float, float, float]:
    """Rotate ``v`` by the unit quaternion ``q`` (plain floats: called per joint per sample)."""
    x, y, z, w = (float(c) for c in q)
    vx, vy, vz = (float(c) for c in v)
    # t = 2 u x v ; r = v + w t + u x t
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def parse_urdf(urdf_text: str) -> UrdfTree:
    """Parse the kinematic tree of a URDF; raises ValueError on malformed input."""
    try:
        root = ET.fromstring(urdf_text)
    except ET.ParseError as exc:
        raise ValueError(f"robot description is not valid XML: {exc}") from exc
    if root.tag != "robot":
        raise ValueError(f"robot description root element is <{root.tag}>, expected <robot>")
    links = [link.get("name") for link in root.findall("link")]
    joints: list[UrdfJoint] = []
    for j in root.findall("joint"):
        origin = j.find("origin")
        xyz = _floats(origin.get("xyz") if origin is not None else None, (0.0, 0.0, 0.0))
        rpy = _floats(origin.get("rpy") if origin is not None else None, (0.0, 0.0, 0.0))
        axis_el = j.find("axis")
        axis = _floats(axis_el.get("xyz") if axis_el is not None else None, (1.0, 0.0, 0.0))
        norm = math.sqrt(sum(a * a for a in axis)) or 1.0
        mimic_el = j.find("mimic")
        mimic = None
        if mimic_el is not None:
            mimic = (
                str(mimic_el.get("joint")),
                float(mimic_el.get("multiplier", "1")),
                float(mimic_el.get("offset", "0")),
            )
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None:
            raise ValueError(f"joint {j.get('name')!r} lacks <parent> or <child>")
        joints.append(
            UrdfJoint(
                name=str(j.get("name")),
                kind=str(j.get("type")),
                parent=str(parent.get("link")),
                child=str(child.get("link")),
                xyz=(xyz[0], xyz[1], xyz[2]),
                quat=rpy_to_quat(*rpy),
                axis=(axis[0] / norm, axis[1] / norm, axis[2] / norm),
                mimic=mimic,
            )
        )
    children = {j.child for j in joints}
    roots = [name for name in links if name not in children]
    if len(roots) != 1:
        raise ValueError(f"robot description must have exactly one root link, found {roots}")
    return UrdfTree(root=str(roots[0]), joints=tuple(joints))


def joint_transforms(
    tree: UrdfTree, positions: Mapping[str, float]
) -> list[tuple[str, str, tuple[float, float, float], tuple[float, float, float, float]]]:
    """(parent, child, translation, rotation) of every moving joint at ``positions``.

    Joints missing from ``positions`` (and not mimicking one present) stay at zero.
    """
    out = []
    for j in tree.moving:
        if j.mimic is not None:
            master, mult, offset = j.mimic
            q = mult * float(positions.get(master, 0.0)) + offset
        else:
            q = float(positions.get(j.name, 0.0))
        if j.kind in ("revolute", "continuous"):
            half = q / 2.0
            s = math.sin(half)
            motion = (j.axis[0] * s, j.axis[1] * s, j.axis[2] * s, math.cos(half))
            out.append((j.parent, j.child, j.xyz, quat_mul(j.quat, motion)))
        elif j.kind == "prismatic":
            shift = quat_rotate(j.quat, (j.axis[0] * q, j.axis[1] * q, j.axis[2] * q))
            xyz = (j.xyz[0] + shift[0], j.xyz[1] + shift[1], j.xyz[2] + shift[2])
            out.append((j.parent, j.child, xyz, j.quat))
        else:  # floating/planar joints inside a URDF are not animated
            out.append((j.parent, j.child, j.xyz, j.quat))
    return out
