"""Collision primitives of a URDF, per link, as plain data.

The collision checker, the height figure and the pictures all read the model's
primitives (box, cylinder, sphere, capsule) from here, so there is one parser.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from planner.transforms import rpy_to_matrix


@dataclass(frozen=True)
class Primitive:
    link: str
    kind: str  # box | cylinder | sphere | capsule
    dims: tuple[float, ...]  # box (x, y, z); cylinder/capsule (radius, length); sphere (radius,)
    origin: np.ndarray  # 4x4 in the link frame

    def local_points(self) -> np.ndarray:
        """Points bounding the primitive in the link frame (box corners, cylinder rims, sphere extremes)."""
        if self.kind == "box":
            hx, hy, hz = (d / 2 for d in self.dims)
            pts = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        elif self.kind in ("cylinder", "capsule"):
            r, length = self.dims
            ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
            ring = np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)
            half = length / 2 + (r if self.kind == "capsule" else 0.0)
            pts = np.vstack([np.column_stack([ring, np.full(16, z)]) for z in (-half, half)])
        else:
            r = self.dims[0]
            pts = np.vstack([np.eye(3) * r, -np.eye(3) * r])
        return pts @ self.origin[:3, :3].T + self.origin[:3, 3]


def _origin(elem: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if elem is None:
        return T
    xyz = [float(v) for v in elem.attrib.get("xyz", "0 0 0").split()]
    T[:3, :3] = rpy_to_matrix(*(float(v) for v in elem.attrib.get("rpy", "0 0 0").split()))
    T[:3, 3] = xyz
    return T


@lru_cache(maxsize=16)
def collision_primitives(urdf: Path) -> tuple[Primitive, ...]:
    """Every primitive collision shape of the URDF (mesh collisions are skipped)."""
    out: list[Primitive] = []
    for link in ET.parse(urdf).getroot().iter("link"):
        for col in link.findall("collision"):
            geom = col.find("geometry")
            if geom is None or len(geom) == 0:
                continue
            shape = geom[0]
            if shape.tag == "box":
                dims = tuple(float(v) for v in shape.attrib["size"].split())
            elif shape.tag in ("cylinder", "capsule"):
                dims = (float(shape.attrib["radius"]), float(shape.attrib["length"]))
            elif shape.tag == "sphere":
                dims = (float(shape.attrib["radius"]),)
            else:
                continue
            out.append(Primitive(link.attrib["name"], shape.tag, dims, _origin(col.find("origin"))))
    return tuple(out)
