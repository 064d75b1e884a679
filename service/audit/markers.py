"""foxglove.SceneUpdate bodies: support polygon, CoM, ZMP, the object, the tables, ground paths.

Pure functions of their inputs (no writer state). Each body carries what is new at
its instant only: the CoM marker is the CoM now, never the path so far; a plan's whole
planned path is one message of its own (:func:`path_body`), written once.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from .encoding import stamp
from .urdf_frames import WORLD_FRAME

Point2 = Sequence[float]
Point3 = Sequence[float]

# Marker colours (RGBA in [0, 1]).
GREEN = {"r": 0.1, "g": 0.75, "b": 0.3, "a": 1.0}
ORANGE = {"r": 1.0, "g": 0.55, "b": 0.0, "a": 1.0}
RED = {"r": 0.9, "g": 0.1, "b": 0.1, "a": 1.0}
BLUE = {"r": 0.15, "g": 0.35, "b": 0.95, "a": 1.0}
PURPLE = {"r": 0.6, "g": 0.2, "b": 0.8, "a": 1.0}
WHITE = {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}
TABLE = {"r": 0.55, "g": 0.4, "b": 0.25, "a": 0.6}
OBJECT_FREE = {"r": 0.7, "g": 0.7, "b": 0.7, "a": 0.9}
OBJECT_HELD = {"r": 0.95, "g": 0.8, "b": 0.1, "a": 0.9}
IDENTITY_Q = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
IDENTITY_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": IDENTITY_Q}


def v3(p: Sequence[float]) -> dict[str, float]:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


def quat(q: Sequence[float]) -> dict[str, float]:
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def pose7(p: Sequence[float]) -> dict[str, Any]:
    """A foxglove Pose from ``[x, y, z, qx, qy, qz, qw]``."""
    return {"position": v3(p[:3]), "orientation": quat(p[3:7])}


def entity(entity_id: str, ns: int, **primitives: list) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "timestamp": stamp(ns),
        "frame_id": WORLD_FRAME,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
    }
    for key in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        doc[key] = primitives.get(key, [])
    return doc


def update(*entities: dict[str, Any]) -> dict[str, Any]:
    return {"deletions": [], "entities": list(entities)}


def line(points: Sequence[Point3], color: dict, *, loop: bool, thickness: float = 0.006) -> dict[str, Any]:
    return {
        "type": 1 if loop else 0,
        "pose": IDENTITY_POSE,
        "thickness": thickness,
        "scale_invariant": False,
        "points": [v3(p) for p in points],
        "color": color,
        "colors": [],
        "indices": [],
    }


def text(at: Point3, label: str, color: dict) -> dict[str, Any]:
    return {"pose": {"position": v3(at), "orientation": IDENTITY_Q}, "billboard": True, "font_size": 12.0,
            "scale_invariant": True, "color": color, "text": label}


def sphere(at: Point3, diameter: float, color: dict) -> dict[str, Any]:
    return {"pose": {"position": v3(at), "orientation": IDENTITY_Q},
            "size": {"x": diameter, "y": diameter, "z": diameter}, "color": color}


def shrink_polygon(polygon: Sequence[Point2], distance_m: float) -> list[list[float]]:
    """The polygon offset inward by ``distance_m`` (empty if nothing is left)."""
    from shapely.geometry import Polygon

    if len(polygon) < 3 or distance_m <= 0:
        return [list(map(float, p)) for p in polygon]
    inner = Polygon([(float(x), float(y)) for x, y in polygon]).buffer(-distance_m, join_style=2)
    if inner.is_empty or inner.geom_type != "Polygon":
        return []
    coords = list(inner.exterior.coords)[:-1]
    return [[float(x), float(y)] for x, y in coords]


def signed_distance(polygon: Sequence[Point2], points: np.ndarray) -> np.ndarray:
    """Signed distance of 2D points to the polygon's boundary, inside positive (the contract's margin)."""
    import shapely
    from shapely.geometry import Polygon

    poly = Polygon([(float(x), float(y)) for x, y in polygon])
    pts = shapely.points(np.asarray(points, dtype=float).reshape(-1, 2))
    dist = shapely.distance(poly.exterior, pts)
    return np.where(shapely.contains(poly, pts), dist, -dist)


def support_body(polygon: Sequence[Point2], shrunk: Sequence[Point2] | None, threshold_m: float | None, ns: int,
                 lift_m: float) -> dict[str, Any]:
    """The support polygon (green) and the polygon shrunk by the threshold (orange)."""
    z = lift_m
    lines = [line([(p[0], p[1], z) for p in polygon], GREEN, loop=True)]
    if shrunk is None and threshold_m is not None:
        shrunk = shrink_polygon(polygon, threshold_m)
    if shrunk:
        lines.append(line([(p[0], p[1], z) for p in shrunk], ORANGE, loop=True, thickness=0.004))
    label = "support polygon" + (f", threshold {threshold_m * 1000:.0f} mm" if threshold_m is not None else "")
    texts = []
    if len(polygon):
        cx = float(np.mean([p[0] for p in polygon]))
        ymin = float(min(p[1] for p in polygon))
        texts.append(text((cx, ymin - 0.05, z), label, WHITE))
    return update(entity("support", ns, lines=lines, texts=texts))


def com_body(com: Point3, margin_m: float | None, threshold_m: float | None, trace: Sequence[Point3] | None, ns: int,
             diameter_m: float, lift_m: float) -> dict[str, Any]:
    """The CoM now: a sphere (red below the threshold), its drop line to the ground and its margin.

    ``trace`` adds a ground path given by the caller (the writer's own playback never passes one).
    """
    ok = margin_m is None or threshold_m is None or margin_m >= threshold_m
    color = BLUE if ok else RED
    ground = (com[0], com[1], lift_m)
    lines = [line([com, ground], color, loop=False, thickness=0.003)]
    if trace:
        lines.append(line([(p[0], p[1], lift_m) for p in trace], BLUE, loop=False, thickness=0.003))
    texts = [] if margin_m is None else [text((com[0], com[1], com[2] + 0.06), f"margin {margin_m * 1000:.1f} mm", color)]
    return update(entity("com", ns, spheres=[sphere(com, diameter_m, color)], lines=lines, texts=texts))


def zmp_body(zmp: Point2, inside: bool, ns: int, diameter_m: float, lift_m: float) -> dict[str, Any]:
    """The ZMP now: a flat disc on the floor (purple inside the polygon, red outside)."""
    color = PURPLE if inside else RED
    disc = {"pose": {"position": v3((zmp[0], zmp[1], lift_m)), "orientation": IDENTITY_Q},
            "size": {"x": diameter_m, "y": diameter_m, "z": 0.002}, "bottom_scale": 1.0, "top_scale": 1.0,
            "color": color}
    return update(entity("zmp", ns, cylinders=[disc]))


def cop_body(cop: Point2, inside: bool, ns: int, diameter_m: float, lift_m: float) -> dict[str, Any]:
    """The robot's measured centre of pressure now: an orange ring-like disc on the floor (red outside)."""
    disc = {"pose": {"position": v3((cop[0], cop[1], 1.5 * lift_m)), "orientation": IDENTITY_Q},
            "size": {"x": diameter_m, "y": diameter_m, "z": 0.002}, "bottom_scale": 1.0, "top_scale": 1.0,
            "color": ORANGE if inside else RED}
    return update(entity("cop", ns, cylinders=[disc]))


def object_primitives(shape: Mapping[str, Any] | None, pose: Sequence[float], color: dict) -> dict[str, list]:
    """The object at ``pose`` as Foxglove primitives (object frames as planner/objects.py defines them).

    A box is centred on its frame; a bar stands on its bottom end face; a cylinder ``[radius, height]``
    is centred with its axis along z; a mesh or a drill, whose outline the plan does not carry, is a
    0.1 m cube at its frame.
    """
    shape = shape or {}
    kind = shape.get("shape")
    size = shape.get("size") or []
    p = np.asarray(pose[:3], dtype=float)
    q = np.asarray(pose[3:7], dtype=float)
    if kind == "cylinder" and len(size) == 2:
        r, h = float(size[0]), float(size[1])
        return {"cylinders": [{"pose": pose7(pose), "size": {"x": 2 * r, "y": 2 * r, "z": h}, "bottom_scale": 1.0,
                               "top_scale": 1.0, "color": color}]}
    dims = [float(v) for v in size] if kind in ("box", "bar", "drill") and len(size) == 3 else [0.1, 0.1, 0.1]
    if kind == "bar":  # frame at the bottom end face: the centre is z/2 up the object's own z axis
        p = p + _rotate(q, np.array([0.0, 0.0, dims[2] / 2]))
    return {"cubes": [{"pose": {"position": v3(p), "orientation": quat(q)}, "size": v3(dims), "color": color}]}


def object_body(shape: Mapping[str, Any] | None, pose: Sequence[float], held: bool, ns: int) -> dict[str, Any]:
    """The object now, yellow while a hand holds it."""
    return update(entity("object", ns, **object_primitives(shape, pose, OBJECT_HELD if held else OBJECT_FREE)))


def tables_entities(tables: Sequence[Mapping[str, Any]], ns: int) -> list[dict[str, Any]]:
    """The scenario's tables (and obstacles): boxes with ``pose`` at their centre and ``size``."""
    out = []
    for k, table in enumerate(tables):
        pose, size = table.get("pose"), table.get("size")
        if not (isinstance(pose, list) and len(pose) == 7 and isinstance(size, list) and len(size) == 3):
            continue
        name = str(table.get("name") or f"table {k}")
        cube = {"pose": pose7(pose), "size": v3(size), "color": TABLE}
        out.append(entity(f"table/{name}", ns, cubes=[cube]))
    return out


def path_body(com_path: Sequence[Point3], zmp_path: Sequence[Point2], tables: Sequence[Mapping[str, Any]], ns: int,
              lift_m: float) -> dict[str, Any]:
    """What a plan shows for its whole duration, once: the tables and the planned CoM and ZMP ground paths."""
    entities = tables_entities(tables, ns)
    if len(com_path) >= 2:
        entities.append(entity("com_path", ns, lines=[line([(p[0], p[1], lift_m) for p in com_path], BLUE,
                                                           loop=False, thickness=0.003)]))
    if len(zmp_path) >= 2:
        entities.append(entity("zmp_path", ns, lines=[line([(p[0], p[1], lift_m) for p in zmp_path], PURPLE,
                                                           loop=False, thickness=0.002)]))
    return update(*entities)


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[x, y, z, w]`` applied to a vector."""
    u, w = q[:3], q[3]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)
