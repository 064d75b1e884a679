"""Static stability: the support polygon and the CoM margin.

A state is stable when the ground projection of the robot + held object CoM lies
inside the support polygon (convex hull of the soles in contact) at least
``threshold`` from its edge. The margin is signed: positive inside, negative
outside, so a margin below the threshold reads directly as "how far from stable".
"""

from __future__ import annotations

import math

import numpy as np

from planner.errors import DegeneratePolygonError


def convex_hull_ccw(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (monotone chain), collinear points dropped."""
    pts = np.unique(np.round(np.asarray(points, dtype=float), 12), axis=0)
    if len(pts) < 3:
        return pts
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 1e-15:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 1e-15:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def sole_corners(R: np.ndarray, p: np.ndarray, length: float, width: float) -> np.ndarray:
    """Ground-plane (x, y) corners of a sole rectangle centred at frame (R, p)."""
    hx, hy = length / 2.0, width / 2.0
    local = np.array([[hx, hy, 0.0], [-hx, hy, 0.0], [-hx, -hy, 0.0], [hx, -hy, 0.0]])
    return (local @ np.asarray(R).T + np.asarray(p))[:, :2]


def support_polygon(soles: list[tuple[np.ndarray, np.ndarray, float, float, bool]]) -> np.ndarray:
    """Convex hull (CCW) of the soles in contact; each sole is (R, p, length, width, in_contact)."""
    corners = [sole_corners(R, p, length, width) for R, p, length, width, contact in soles if contact]
    if not corners:
        raise DegeneratePolygonError("no foot is in contact with the ground")
    return convex_hull_ccw(np.vstack(corners))


class SupportPolygon:
    """A convex polygon with precomputed edge normals for fast signed distances."""

    def __init__(self, vertices: np.ndarray):
        v = np.asarray(vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
            raise DegeneratePolygonError(f"support polygon needs at least 3 corners, got {len(v)}")
        area = 0.5 * np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
        if area <= 1e-9:
            raise DegeneratePolygonError(f"support polygon has no area ({area:.3g} m^2) or is not counter-clockwise")
        self.vertices = v
        self.edges_start = v
        self.edges_vec = np.roll(v, -1, axis=0) - v
        lengths = np.linalg.norm(self.edges_vec, axis=1)
        self.edge_len2 = lengths**2
        # Inward unit normals of a CCW polygon: rotate the edge +90 degrees.
        self.normals = np.stack([-self.edges_vec[:, 1], self.edges_vec[:, 0]], axis=1) / lengths[:, None]
        self.offsets = np.einsum("ij,ij->i", self.normals, v)
        self._edges = [
            (float(n[0]), float(n[1]), float(o)) for n, o in zip(self.normals, self.offsets)
        ]
        self._segs = [
            (float(a[0]), float(a[1]), float(e[0]), float(e[1]), float(l2))
            for a, e, l2 in zip(v, self.edges_vec, self.edge_len2)
        ]

    @property
    def inradius(self) -> float:
        """Largest margin any point can have (the largest inscribed circle's radius)."""
        from scipy.optimize import linprog

        # maximise r s.t. n_i . c - o_i >= r
        A = np.hstack([-self.normals, np.ones((len(self.normals), 1))])
        res = linprog(c=[0, 0, -1], A_ub=A, b_ub=-self.offsets, bounds=[(None, None), (None, None), (0, None)])
        return float(res.x[2]) if res.success else 0.0

    def margin(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of many (x, y) points to the polygon edge; inside positive. (N,)"""
        pts = np.asarray(points, dtype=float)[..., :2]
        d_lines = pts @ self.normals.T - self.offsets  # (N, E): distance to each edge line
        inside = d_lines.min(axis=1)
        out = inside.copy()
        outside = inside < 0
        if np.any(outside):
            q = pts[outside]
            rel = q[:, None, :] - self.edges_start[None, :, :]
            t = np.clip(np.einsum("nek,ek->ne", rel, self.edges_vec) / self.edge_len2, 0.0, 1.0)
            closest = self.edges_start[None] + t[..., None] * self.edges_vec[None]
            out[outside] = -np.sqrt(((q[:, None, :] - closest) ** 2).sum(-1)).min(axis=1)
        return out

    def edge_distances(self, point: np.ndarray) -> np.ndarray:
        """Signed distance of one (x, y) point to each edge's line, inside positive (E,): the margin is
        their minimum while the point is inside (linear in the point, for solvers)."""
        return self.normals @ point - self.offsets

    def margin_one(self, x: float, y: float) -> float:
        """Signed distance of one point, in plain Python (no array overhead)."""
        m = math.inf
        for nx, ny, o in self._edges:
            d = nx * x + ny * y - o
            if d < m:
                m = d
        if m >= 0.0:
            return m
        best = math.inf
        for ax, ay, ex, ey, l2 in self._segs:
            t = ((x - ax) * ex + (y - ay) * ey) / l2
            t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
            dx, dy = x - (ax + t * ex), y - (ay + t * ey)
            d2 = dx * dx + dy * dy
            if d2 < best:
                best = d2
        return -math.sqrt(best)
