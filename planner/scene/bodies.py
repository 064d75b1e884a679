"""Collision bodies: the shapes the collision checker compares, with their bounding boxes and
python-fcl geometries (objects, tables and obstacles, a hand's shapes), and the pairwise test of
two shape sets that grasp planning and handover poses use."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import fcl
import numpy as np

from planner.compiled.box_kernels import hypotheses_hit
from planner.scene.objects import ObjectModel
from planner.transforms import pose7_to_matrix


@dataclass(frozen=True)
class EnvBox:
    """A static box of the environment (table or obstacle)."""

    name: str
    pose: np.ndarray  # 4x4 of the box centre in the world
    size: tuple[float, float, float]


@dataclass
class Body:
    name: str
    group: str  # robot | env | object
    kind: str  # box | cylinder | sphere | capsule | mesh
    dims: tuple[float, ...]
    local: np.ndarray  # 4x4: parent (joint, world or object frame) -> shape centre
    half: np.ndarray  # half sizes of the oriented bounding box (shape frame)
    obb_offset: np.ndarray  # OBB centre in the shape frame (non-zero only for meshes)
    joint: int = -1  # pinocchio joint id for robot bodies
    link: str = ""
    geometry: object = field(default=None, repr=False)


def fcl_geometry(kind: str, dims: tuple[float, ...], mesh=None):
    if kind == "box":
        return fcl.Box(*dims)
    if kind == "cylinder":
        return fcl.Cylinder(dims[0], dims[1])
    if kind == "capsule":
        return fcl.Capsule(dims[0], dims[1])
    if kind == "sphere":
        return fcl.Sphere(dims[0])
    if kind == "mesh":
        bvh = fcl.BVHModel()
        bvh.beginModel(len(mesh.vertices), len(mesh.faces))
        bvh.addSubModel(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int32))
        bvh.endModel()
        return bvh
    raise ValueError(f"unsupported collision shape {kind!r}")


def half_extents(kind: str, dims: tuple[float, ...]) -> np.ndarray:
    if kind == "box":
        return np.asarray(dims, dtype=float) / 2.0
    if kind == "cylinder":
        return np.array([dims[0], dims[0], dims[1] / 2.0])
    if kind == "capsule":
        return np.array([dims[0], dims[0], dims[1] / 2.0 + dims[0]])
    if kind == "sphere":
        return np.full(3, dims[0])
    raise ValueError(f"unsupported collision shape {kind!r}")


def object_bodies(obj: ObjectModel) -> list[Body]:
    """Collision bodies of an object in its frame: its primitives, or one BVH for a mesh."""
    out = []
    if obj.primitives:
        for k, p in enumerate(obj.primitives):
            out.append(Body(f"object#{k}" if len(obj.primitives) > 1 else "object", "object", p.kind, p.dims, p.origin,
                             half_extents(p.kind, p.dims), np.zeros(3), geometry=fcl_geometry(p.kind, p.dims)))
    else:
        # the mesh in its own frame; the OBB is the axis-aligned box of the vertices
        lo, hi = obj.mesh.bounds
        out.append(Body("object", "object", "mesh", (), np.eye(4), (hi - lo) / 2.0, (hi + lo) / 2.0,
                         geometry=fcl_geometry("mesh", (), obj.mesh)))
    return out


def make_fcl_object(body: Body) -> fcl.CollisionObject:
    return fcl.CollisionObject(body.geometry, fcl.Transform())


def fcl_collide(oa: fcl.CollisionObject, ob: fcl.CollisionObject, tolerance: float) -> bool:
    if tolerance <= 0.0:
        return fcl.collide(oa, ob, fcl.CollisionRequest(), fcl.CollisionResult()) > 0
    req = fcl.CollisionRequest(num_max_contacts=4, enable_contact=True)
    res = fcl.CollisionResult()
    if fcl.collide(oa, ob, req, res) == 0:
        return False
    return max(c.penetration_depth for c in res.contacts) > tolerance


def set_fcl_transform(o: fcl.CollisionObject, R: np.ndarray, p: np.ndarray) -> None:
    o.setTransform(fcl.Transform(R, p))


def shapes_collide(
    bodies_a: Sequence[Body], poses_a: np.ndarray, bodies_b: Sequence[Body], poses_b: np.ndarray, tolerance: float = 0.0
) -> np.ndarray:
    """Whether any body of set a collides with any body of set b, for K pose hypotheses.

    ``poses_a`` (K, len(a), 4, 4) and ``poses_b`` (K, len(b), 4, 4) or (len(b), 4, 4) are the
    poses of the bodies' shape frames (their ``local`` transforms already applied). Used by
    the grasp and handover filters, which test many hand poses against one object.
    """
    K = poses_a.shape[0]
    poses_b = np.broadcast_to(poses_b, (K, len(bodies_b), 4, 4))

    def boxes(bodies: Sequence[Body], poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        R = poses[..., :3, :3]
        centres = poses[..., :3, 3] + (R @ np.array([b.obb_offset for b in bodies])[None, :, :, None])[..., 0]
        return R, centres, np.array([b.half for b in bodies])

    is_box = np.array([b.kind == "box" for b in bodies_a]), np.array([b.kind == "box" for b in bodies_b])
    # Every box pair screened at once (compiled): two boxes are decided there (the SAT is exact for
    # boxes); the other shapes' candidates go to fcl, pair by pair, until one hypothesis collides.
    hit, cand = hypotheses_hit(*boxes(bodies_a, poses_a), *boxes(bodies_b, poses_b), *is_box, tolerance)
    objs_a = [make_fcl_object(b) for b in bodies_a]
    objs_b = [make_fcl_object(b) for b in bodies_b]
    for k, ia, ib in cand:
        if hit[k]:
            continue
        set_fcl_transform(objs_a[ia], poses_a[k, ia, :3, :3], poses_a[k, ia, :3, 3])
        set_fcl_transform(objs_b[ib], poses_b[k, ib, :3, :3], poses_b[k, ib, :3, 3])
        hit[k] = fcl_collide(objs_a[ia], objs_b[ib], tolerance)
    return hit


def environment_boxes(scenario) -> list[EnvBox]:
    """Tables and obstacles of a scenario as :class:`EnvBox` (tables first)."""
    return [EnvBox(b.name, pose7_to_matrix(b.pose), tuple(b.size)) for b in [*scenario.tables, *scenario.obstacles]]


