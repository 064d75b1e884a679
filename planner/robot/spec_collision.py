"""A robot spec's explicit collision shapes: primitives given per link, written into the derived URDF.

``collision: auto`` (the default) keeps the URDF's primitives and fits boxes to its meshes. A mapping
``{LINK: [SHAPE, ...], ...}`` replaces the listed links' collision elements with the given shapes (an
empty list: the link has none), and every other link is treated as ``auto``. This is how a URDF whose
links carry no collision at all (a hand with only a visual mesh) or only token ones (four 5 mm spheres
under a foot) gets shapes the planner and the gate can check.

A shape is one of ``{box: [x, y, z]}``, ``{sphere: r}``, ``{cylinder: [radius, length]}`` or
``{capsule: [radius, length]}`` (cylinders and capsules along their z axis, ``length`` between the
capsule's sphere centres), with an optional ``pose: [x, y, z, qx, qy, qz, qw]`` in the link frame. URDF
has no capsule, so a capsule is written as its cylinder and its two end spheres: the same volume.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Callable

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError, model_validator


class CollisionShape(BaseModel):
    """One primitive of a link, in the link frame (metres)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    box: tuple[float, float, float] | None = None
    sphere: float | None = None
    cylinder: tuple[float, float] | None = None
    capsule: tuple[float, float] | None = None
    pose: tuple[float, float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)

    @model_validator(mode="after")
    def _one_positive_shape(self) -> "CollisionShape":
        given = [k for k in ("box", "sphere", "cylinder", "capsule") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of box, sphere, cylinder, capsule (got {', '.join(given) or 'none'})")
        dims = np.atleast_1d(np.asarray(getattr(self, given[0]), dtype=float))
        if not (np.all(np.isfinite(dims)) and np.all(dims > 0)):
            raise ValueError(f"{given[0]}: sizes in metres, finite and positive (got {getattr(self, given[0])})")
        if not np.all(np.isfinite(self.pose)) or np.linalg.norm(self.pose[3:]) < 1e-9:
            raise ValueError("pose: [x, y, z, qx, qy, qz, qw] with a non-zero quaternion")
        return self


LinkShapes = dict[str, list[CollisionShape]]


def parse_collision(value: object, error: Callable[[str], Exception]) -> LinkShapes | None:
    """The spec's ``collision`` field: None for ``auto``, else the shapes per link; ``error(message)`` makes
    the exception a bad entry raises, its message starting with the field's path."""
    if value == "auto":
        return None
    if not isinstance(value, dict):
        raise error(f"collision: `auto` or a mapping of link names to lists of shapes, got {value!r}")
    out: LinkShapes = {}
    for link, shapes in value.items():
        if not isinstance(shapes, list):
            raise error(f"collision.{link}: a list of shapes, got {shapes!r}")
        out[str(link)] = []
        for k, shape in enumerate(shapes):
            try:
                out[str(link)].append(CollisionShape.model_validate(shape))
            except ValidationError as exc:
                first = exc.errors()[0]
                where = ".".join(str(p) for p in first["loc"])
                raise error(f"collision.{link}[{k}]{'.' + where if where else ''}: {first['msg']}") from None
    return out


def write_link_shapes(link_el: ET.Element, shapes: list[CollisionShape]) -> None:
    """Replace ``link_el``'s collision elements with ``shapes``."""
    for old in link_el.findall("collision"):
        link_el.remove(old)
    for shape in shapes:
        for kind, dims, pose in _urdf_primitives(shape):
            col = ET.SubElement(link_el, "collision")
            xyz, rpy = urdf_origin(list(pose))
            ET.SubElement(col, "origin", {"xyz": xyz, "rpy": rpy})
            geo = ET.SubElement(col, "geometry")
            if kind == "box":
                ET.SubElement(geo, "box", {"size": " ".join(repr(float(v)) for v in dims)})
            elif kind == "sphere":
                ET.SubElement(geo, "sphere", {"radius": repr(float(dims[0]))})
            else:
                ET.SubElement(geo, "cylinder", {"radius": repr(float(dims[0])), "length": repr(float(dims[1]))})


def urdf_origin(pose: list[float]) -> tuple[str, str]:
    """A pose ``[x, y, z, qx, qy, qz, qw]`` as a URDF ``<origin>``'s ``xyz`` and ``rpy`` attribute strings; a zero
    quaternion raises ValueError."""
    x, y, z, qx, qy, qz, qw = pose
    n = float(np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw))
    if n < 1e-9:
        raise ValueError("zero quaternion")
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    roll = np.arctan2(2 * (qw * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy))
    pitch = np.arcsin(np.clip(2 * (qw * qy - qz * qx), -1.0, 1.0))
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    return f"{x!r} {y!r} {z!r}", f"{float(roll)!r} {float(pitch)!r} {float(yaw)!r}"


def _urdf_primitives(shape: CollisionShape) -> list[tuple[str, tuple[float, ...], tuple[float, ...]]]:
    """(URDF kind, dims, pose) of one shape; a capsule as its cylinder and two end spheres."""
    if shape.box is not None:
        return [("box", shape.box, shape.pose)]
    if shape.sphere is not None:
        return [("sphere", (shape.sphere,), shape.pose)]
    if shape.cylinder is not None:
        return [("cylinder", shape.cylinder, shape.pose)]
    radius, length = shape.capsule  # type: ignore[misc]
    x, y, z, qx, qy, qz, qw = shape.pose
    q = np.array([qx, qy, qz, qw]) / np.linalg.norm([qx, qy, qz, qw])
    axis = _rotate(q, np.array([0.0, 0.0, 1.0]))
    ends = [tuple(float(v) for v in (*(np.array([x, y, z]) + s * (length / 2) * axis), *q)) for s in (1.0, -1.0)]
    return [("cylinder", (radius, length), shape.pose), *(("sphere", (radius,), e) for e in ends)]


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` rotated by the unit quaternion ``q`` (x, y, z, w)."""
    u, w = q[:3], q[3]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)
