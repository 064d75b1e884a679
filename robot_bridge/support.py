"""The gate's own support polygon and signed distances (inside positive), in numpy.

Recomputed from the URDF sole boxes at the stance's foot placements, never taken
from the plan file: a plan that lies about its polygon is checked against the
real one.
"""

from __future__ import annotations

import numpy as np

from .errors import BridgeError
from .urdf_kinematics import UrdfModel, quaternion_matrix


class PolygonError(BridgeError, ValueError):
    """No support: no foot in contact, or a polygon without area."""


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull of (x, y) points (Andrew's monotone chain), collinear points dropped."""
    pts = sorted({(float(x), float(y)) for x, y in np.asarray(points, dtype=float)})
    if len(pts) < 3:
        return np.array(pts)

    def turn(o: tuple, a: tuple, b: tuple) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    chains = []
    for sweep in (pts, pts[::-1]):  # lower chain left to right, upper chain right to left
        chain: list = []
        for p in sweep:
            while len(chain) >= 2 and turn(chain[-2], chain[-1], p) <= 1e-15:
                chain.pop()
            chain.append(p)
        chains.append(chain[:-1])  # each chain's last point starts the other
    return np.array(chains[0] + chains[1])


def sole_footprint(model: UrdfModel, frame: str, pose: np.ndarray) -> np.ndarray:
    """Ground (x, y) corners of a sole's collision box with the sole frame at ``pose`` [7]."""
    size, origin, R_box = model.sole_box(frame)
    hx, hy = size[0] / 2.0, size[1] / 2.0
    local = np.array([[hx, hy, 0.0], [-hx, hy, 0.0], [-hx, -hy, 0.0], [hx, -hy, 0.0]])
    in_sole = local @ R_box.T + np.array([origin[0], origin[1], 0.0])
    pose = np.asarray(pose, dtype=float)
    world = in_sole @ quaternion_matrix(pose[3:]).T + pose[:3]
    return world[:, :2]


class Polygon:
    """A convex CCW polygon with signed distances (inside positive)."""

    def __init__(self, vertices: np.ndarray):
        v = np.asarray(vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
            raise PolygonError(f"the support polygon needs at least 3 corners, got {len(v)}")
        edges = np.roll(v, -1, axis=0) - v
        area = 0.5 * float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
        if area <= 1e-9:
            raise PolygonError(f"the support polygon has no area ({area:.3g} m^2)")
        self.vertices = v
        self._start = v
        self._edges = edges
        self._len2 = np.einsum("ij,ij->i", edges, edges)
        lengths = np.sqrt(self._len2)
        self._normals = np.stack([-edges[:, 1], edges[:, 0]], axis=1) / lengths[:, None]  # inward for CCW
        self._offsets = np.einsum("ij,ij->i", self._normals, v)

    def margin(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of (N, 2) points to the boundary: inside positive, outside negative."""
        pts = np.asarray(points, dtype=float)[:, :2]
        d = (pts @ self._normals.T - self._offsets).min(axis=1)
        outside = d < 0.0
        if np.any(outside):
            q = pts[outside]
            rel = q[:, None, :] - self._start[None]
            t = np.clip(np.einsum("nek,ek->ne", rel, self._edges) / self._len2, 0.0, 1.0)
            nearest = self._start[None] + t[..., None] * self._edges[None]
            d[outside] = -np.sqrt(((q[:, None, :] - nearest) ** 2).sum(-1)).min(axis=1)
        return d


def support_polygon(model: UrdfModel, feet: list[dict]) -> Polygon:
    """Convex hull of the sole boxes of the feet with ``in_contact`` true."""
    corners = [sole_footprint(model, f["frame"], f["pose"]) for f in feet if f.get("in_contact", True)]
    if not corners:
        raise PolygonError("no foot is in contact with the ground")
    return Polygon(convex_hull(np.vstack(corners)))
