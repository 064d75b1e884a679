"""Resting poses of the object: reference poses from its convex hull, instantiated on tables.

Reference poses live in the object's own data (computed once per object): each facet of the
convex hull is a way to lie on a flat surface. It is kept when the CoM projects inside the
facet with (distance to the facet's edge) / (CoM height) >= ``stability_ratio``: the object
then tips only under a push of that ratio times its weight. A reference pose is given as
``T_ref``: the object frame in a "contact" frame whose z = 0 plane is the table top and whose
origin lies under the CoM.

Instantiated placements (per scenario) put reference poses at table spots x yaw angles, and
always include the scenario's start and goal poses, which :func:`check_resting` validates
with messages that say what is wrong and by how much.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.errors import PlacementError
from planner.scene.bodies import EnvBox
from planner.scene.collision import CollisionWorld
from planner.scene.objects import ObjectModel
from planner.stability.support_polygon import (
    DegeneratePolygonError,
    SupportPolygon,
    convex_hull_ccw,
)
from planner.transforms import frame_from_z, matrix_to_pose7, pose7_to_matrix, rot_z, rotation_angle

#: Facet normals closer than this are one facet (the hull of a mesh has split coplanar faces).
_COPLANAR_COS = 1.0 - 1e-9


class PlacementSettings(BaseModel):
    """Parameters of placements (SI units, radians)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stability_ratio: float = Field(0.1, ge=0, description="(CoM distance to the support edge) / (CoM height), minimum")
    yaws: int = Field(8, ge=1, le=360, description="yaw angles per table spot")
    spot_spacing_m: float = Field(0.10, gt=0, description="grid spacing of table spots")
    edge_margin_m: float = Field(0.02, ge=0, description="the footprint stays this far inside the table top")
    rest_tolerance_m: float = Field(0.003, gt=0, description="a resting object's lowest point is within this of the table top")
    match_angle_rad: float = Field(0.05, gt=0, description="a pose matches a reference pose when its down axis is within this")
    region: tuple[float, float, float, float] | None = Field(
        None, description="optional world (x_min, x_max, y_min, y_max) that spots must lie in (e.g. the robot's reach)"
    )


@dataclass(frozen=True)
class ReferencePose:
    """One way of lying on a flat surface, in the object's data (no table, no yaw)."""

    index: int
    T_ref: np.ndarray  # object frame in the contact frame (table top z = 0, CoM above the origin)
    down_local: np.ndarray  # unit vector of the object frame that points down (the facet normal)
    com_height_m: float
    stability_ratio: float
    footprint: np.ndarray  # (k, 2) support polygon in the contact frame


@dataclass(frozen=True)
class Placement:
    """A resting pose on a table: an instantiated reference pose, the start, or the goal."""

    id: int
    kind: str  # "start" | "goal" | "spot"
    table: str
    reference: int  # index of the matching reference pose, -1 when none matches
    yaw: float
    T_world_obj: np.ndarray

    def pose7(self) -> list[float]:
        return matrix_to_pose7(self.T_world_obj).tolist()


@dataclass(frozen=True)
class RestingInfo:
    """What :func:`check_resting` found out about a valid resting pose."""

    table: str
    reference: int
    gap_m: float  # lowest point minus table top (within the tolerance)
    stability_ratio: float


def _signed_distance(points: np.ndarray, p: np.ndarray) -> float | None:
    """Signed distance of ``p`` to the edge of the hull of ``points`` (inside positive), or None if it has no area."""
    hull = convex_hull_ccw(points)
    if len(hull) < 3:
        return None
    try:
        return SupportPolygon(hull).margin_one(float(p[0]), float(p[1]))
    except DegeneratePolygonError:
        return None


def _down_frame(n: np.ndarray) -> np.ndarray:
    """Rotation taking the object's unit vector ``n`` to world -z, with a deterministic yaw."""
    # rows: the object's vectors expressed in the contact frame
    return frame_from_z(-np.asarray(n, float)).T.copy()


def reference_poses(obj: ObjectModel, settings: PlacementSettings | None = None) -> list[ReferencePose]:
    """Stable resting poses of the object's convex hull, most stable first."""
    settings = settings or PlacementSettings()
    hull = obj.mesh.convex_hull
    normals = np.asarray(hull.face_normals)
    verts = np.asarray(hull.vertices)
    com = np.asarray(obj.com_local, float)
    # group faces into facets by normal (the hull is convex: equal normals = same plane)
    groups: list[np.ndarray] = []
    for i in range(len(normals)):
        if any(normals[g[0]] @ normals[i] > _COPLANAR_COS for g in groups):
            continue
        groups.append(np.flatnonzero(normals @ normals[i] > _COPLANAR_COS))
    out = []
    for g in groups:
        n = normals[g[0]]
        d = float(np.max(verts @ n))
        h = d - float(n @ com)
        if h <= 1e-9:
            continue  # CoM outside the hull on this side (a point mass far out)
        R = _down_frame(n)
        on_plane = verts[np.abs(verts @ n - d) < 1e-7]
        c_proj = com + h * n
        pts2 = (on_plane - c_proj) @ R.T
        poly = convex_hull_ccw(pts2[:, :2])
        dist = _signed_distance(poly, np.zeros(2))
        if dist is None:
            continue
        ratio = dist / h
        if ratio < settings.stability_ratio:
            continue
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = -R @ c_proj
        out.append((ratio, T, n, h, poly))
    out.sort(key=lambda r: (-round(r[0], 9), tuple(np.round(r[2], 9))))
    return [ReferencePose(i, T, n.copy(), h, ratio, poly) for i, (ratio, T, n, h, poly) in enumerate(out)]


def _table_top(table: EnvBox) -> tuple[float, np.ndarray, np.ndarray]:
    """(top height, world->table xy rotation rows, half sizes xy) of a horizontal table box."""
    R = table.pose[:3, :3]
    if abs(R[2, 2]) < 1 - 1e-6:
        raise PlacementError(f"table {table.name!r} is tilted; tables must be horizontal boxes")
    top = float(table.pose[2, 3] + table.size[2] / 2.0)
    return top, R[:2, :2].T, np.array(table.size[:2]) / 2.0


def _inside_table(table: EnvBox, xy: np.ndarray, margin: float) -> bool:
    _top, Rt, half = _table_top(table)
    local = (np.atleast_2d(xy) - table.pose[:2, 3]) @ Rt.T
    return bool(np.all(np.abs(local) <= half - margin + 1e-12))


def match_reference(obj: ObjectModel, refs: Sequence[ReferencePose], T_world_obj: np.ndarray, max_angle: float) -> int:
    """Index of the reference pose whose down axis matches the pose's, or -1."""
    down_local = T_world_obj[:3, :3].T @ np.array([0.0, 0.0, -1.0])
    best, best_angle = -1, max_angle
    for r in refs:
        angle = float(np.arccos(np.clip(down_local @ r.down_local, -1.0, 1.0)))
        if angle <= best_angle:
            best, best_angle = r.index, angle
    return best


def check_resting(
    obj: ObjectModel,
    T_world_obj: np.ndarray,
    tables: Iterable[EnvBox],
    settings: PlacementSettings | None = None,
    what: str = "pose",
    refs: Sequence[ReferencePose] | None = None,
) -> RestingInfo:
    """Validate that the object rests on a table at ``T_world_obj``; raise :class:`PlacementError` otherwise.

    Resting means: the lowest point of the object is on a table top (within
    ``rest_tolerance_m``), the CoM projects onto that table, and the CoM lies over the
    contact polygon (the hull points touching the top), so the object does not tip.
    """
    settings = settings or PlacementSettings()
    tables = list(tables)
    if not tables:
        raise PlacementError(f"{what} cannot rest anywhere: the scenario has no table")
    T = np.asarray(T_world_obj, float)
    hull = np.asarray(obj.mesh.convex_hull.vertices) @ T[:3, :3].T + T[:3, 3]
    com = T[:3, :3] @ obj.com_local + T[:3, 3]
    low = float(hull[:, 2].min())
    # the table under the CoM whose top is nearest to the lowest point
    under = [t for t in tables if _inside_table(t, com[:2], 0.0)]
    if not under:
        names = ", ".join(repr(t.name) for t in tables)
        raise PlacementError(
            f"{what} is not over a table: its CoM projects to ({com[0]:.3f}, {com[1]:.3f}) m, outside every table top ({names})"
        )
    table = min(under, key=lambda t: abs(low - _table_top(t)[0]))
    top = _table_top(table)[0]
    gap = low - top
    if gap > settings.rest_tolerance_m:
        raise PlacementError(f"{what} is not resting on a table: lowest point {gap * 1000:.0f} mm above table {table.name!r}")
    if gap < -settings.rest_tolerance_m:
        raise PlacementError(f"{what} is not resting on a table: it sinks {-gap * 1000:.0f} mm into table {table.name!r}")
    contact = hull[hull[:, 2] <= low + settings.rest_tolerance_m][:, :2]
    height = float(com[2] - low)
    margin = _signed_distance(contact, com[:2])
    if margin is None:
        raise PlacementError(
            f"{what} is not a resting pose: it touches table {table.name!r} on a point or an edge only (it would tip over)"
        )
    ratio = margin / height if height > 1e-9 else np.inf
    if margin < 0:
        raise PlacementError(
            f"{what} is not stable on table {table.name!r}: its CoM projects {-margin * 1000:.0f} mm outside the contact area"
        )
    if not _inside_table(table, contact, 0.0):
        raise PlacementError(f"{what} overhangs the edge of table {table.name!r}: part of its contact area is off the top")
    refs = refs if refs is not None else reference_poses(obj, settings)
    return RestingInfo(table.name, match_reference(obj, refs, T, settings.match_angle_rad), gap, float(ratio))


def _as_env_boxes(tables: Iterable) -> list[EnvBox]:
    out = []
    for t in tables:
        if isinstance(t, EnvBox):
            out.append(t)
        else:  # schemas.scenario.BoxDef
            out.append(EnvBox(t.name, pose7_to_matrix(t.pose), tuple(t.size)))
    return out


def check_resting_pose(
    obj: ObjectModel,
    pose: Sequence[float] | np.ndarray,
    tables: Iterable,
    settings: PlacementSettings | None = None,
    what: str = "pose",
) -> RestingInfo:
    """:func:`check_resting` for wire data: a pose ``[x, y, z, qx, qy, qz, qw]`` (or 4x4) and the
    scenario's table boxes (``BoxDef`` or :class:`EnvBox`)."""
    T = np.asarray(pose, dtype=float)
    if T.shape == (7,):
        T = pose7_to_matrix(T)
    return check_resting(obj, T, _as_env_boxes(tables), settings, what=what)


def instantiate_placements(
    obj: ObjectModel,
    tables: Sequence[EnvBox],
    start: np.ndarray,
    goal: np.ndarray,
    settings: PlacementSettings | None = None,
    world: CollisionWorld | None = None,
    refs: Sequence[ReferencePose] | None = None,
) -> list[Placement]:
    """Start, goal, then reference poses at table spots x yaws (ids in that order).

    Spots lie on a grid of ``spot_spacing_m`` over each table top; a placement is kept when
    its footprint is inside the top by ``edge_margin_m``, it lies in ``region`` if given, and
    (with a ``world``) the object there is clear of the obstacles.
    """
    settings = settings or PlacementSettings()
    refs = list(refs) if refs is not None else reference_poses(obj, settings)
    out: list[Placement] = []
    for kind, T in (("start", start), ("goal", goal)):
        try:
            info = check_resting(obj, T, tables, settings, what=f"{kind} pose", refs=refs)
        except PlacementError as exc:
            raise PlacementError(str(exc), end=kind) from None
        yaw = 0.0
        if info.reference >= 0:
            Rref = refs[info.reference].T_ref[:3, :3]
            Rz = np.asarray(T)[:3, :3] @ Rref.T
            yaw = float(np.arctan2(Rz[1, 0], Rz[0, 0]))
        out.append(Placement(len(out), kind, info.table, info.reference, yaw, np.asarray(T, float).copy()))
    hull = np.asarray(obj.mesh.convex_hull.vertices)
    for table in tables:
        top, Rt, half = _table_top(table)
        nx = max(int(np.floor(2 * half[0] / settings.spot_spacing_m)), 0)
        ny = max(int(np.floor(2 * half[1] / settings.spot_spacing_m)), 0)
        xs = (np.arange(nx + 1) - nx / 2.0) * settings.spot_spacing_m
        ys = (np.arange(ny + 1) - ny / 2.0) * settings.spot_spacing_m
        grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)  # x-major, as spots are numbered
        centres = table.pose[:2, 3] + grid @ Rt  # each spot's centre in the world (Rt: world -> table rows)
        for ref in refs:
            for k in range(settings.yaws):
                yaw = 2.0 * np.pi * k / settings.yaws
                Ryaw = np.eye(4)
                Ryaw[:3, :3] = rot_z(yaw)
                T_c = Ryaw @ ref.T_ref
                # the whole object's outline, not only its contact area, stays over the top (all spots at once)
                foot = (hull @ T_c[:3, :3].T + T_c[:3, 3])[:, :2]
                local = (centres[:, None, :] + foot[None, :, :] - table.pose[:2, 3]) @ Rt.T
                inside = np.all(np.abs(local) <= half - settings.edge_margin_m + 1e-12, axis=(1, 2))
                for centre in centres[inside]:
                    if settings.region is not None:
                        x0, x1, y0, y1 = settings.region
                        if not (x0 <= centre[0] <= x1 and y0 <= centre[1] <= y1):
                            continue
                    T = T_c.copy()
                    T[:3, 3] += np.array([centre[0], centre[1], top])
                    if world is not None and world.object_pose_clear(T) is not None:
                        continue
                    out.append(Placement(len(out), "spot", table.name, ref.index, yaw, T))
    return out


def same_pose(Ta: np.ndarray, Tb: np.ndarray, pos_tol: float = 1e-3, ang_tol: float = 1e-2) -> bool:
    """Whether two object poses coincide within tolerances (m, rad)."""
    return bool(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]) <= pos_tol and rotation_angle(Ta[:3, :3], Tb[:3, :3]) <= ang_tol)
