"""Antipodal grasps of a parallel jaw, in the object frame, cached on disk per object.

Recipe (the regrasp planners' one, with the parameters named and the order deterministic):

1. sample surface points, area-weighted, with a seeded ``numpy.random.Generator``;
2. from each point cast a ray into the object along the inward normal; the first surface it
   leaves through is the opposite contact. Keep the pair when the normals are anti-parallel
   (``dot < antipodal_cos``) and the width fits the jaw with a clearance on both sides;
3. torque filter: keep grasps whose centre lies within ``max_com_distance_m`` of the CoM, since
   a parallel jaw cannot resist a large gravity torque about its closing axis;
4. merge near-duplicate contact pairs, then rotate the hand about the closing axis
   (``rotations`` approach directions, plus the hand turned half a turn about its approach);
5. drop hand poses where the hand (palm and fingers opened to width + clearance) collides
   with the object; the hand's shapes come from the robot's URDF (:func:`hand_geometry`).

A grasp is ``T_obj_tcp``: the TCP frame in the object frame (z = approach, out of the palm
toward the object; y = closing direction), with the jaw opening and the jaw joint value.
Grasps depend only on the object and the hand, so they are cached as ``.npz`` (no pickle)
under ``REGRASP_CACHE_DIR`` (default ``~/.cache/hrp-regrasp``) keyed by the object's content
hash, the hand geometry and these settings.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from planner.grasping.contact_grasps import CONTACT_ALGORITHM_VERSION, compute_contact_grasps
from planner.grasping.grasp_model import Grasp, GraspSettings, sample_surface, thin_out
from planner.robot.model import RobotModel
from planner.robot.spec import Side
from planner.scene.bodies import object_bodies, shapes_collide
from planner.scene.hand import HandGeometry, hand_bodies, hand_geometry
from planner.scene.objects import ObjectModel
from planner.transforms import perpendicular

CACHE_ENV = "REGRASP_CACHE_DIR"
DEFAULT_CACHE_DIR = Path("~/.cache/hrp-regrasp")
#: Bump when the algorithm changes, so old cache files are not reused.
GRASP_ALGORITHM_VERSION = 1
#: Offset of a ray origin inside the surface, so the ray does not hit its own face.
_RAY_EPS = 1e-7


@dataclass(frozen=True)
class GraspSet:
    """The grasps of one object for one hand, sorted by distance to the CoM (ids = positions)."""

    object_hash: str
    side: str
    grasps: tuple[Grasp, ...]
    from_cache: bool
    seconds: float
    cache_file: str | None = None

    def __len__(self) -> int:
        return len(self.grasps)

    def __getitem__(self, i: int) -> Grasp:
        return self.grasps[i]

    def poses(self) -> np.ndarray:
        """All ``T_obj_tcp`` as (K, 4, 4)."""
        return np.array([g.T_obj_tcp for g in self.grasps]).reshape(-1, 4, 4)


# ---------------------------------------------------------------------------------------------
# geometry helpers


#: Rays x triangles handled per numpy step (bounds the memory of big meshes to ~100 MB).
_RAY_TRI_BUDGET = 1_000_000


def first_hits(mesh: trimesh.Trimesh, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance and face index of each ray's first hit (inf, -1 when none); Moller-Trumbore in numpy.

    Faces whose bounding sphere misses the ray's line are screened out first (a few cheap
    products per ray and face), so big meshes cost little more than small ones.
    """
    tri = np.asarray(mesh.triangles, dtype=float)
    centre = tri.mean(axis=1)
    radius2 = np.max(np.sum((tri - centre[:, None, :]) ** 2, axis=2), axis=1) * (1 + 1e-9) + 1e-18
    n = len(origins)
    dist = np.full(n, np.inf)
    face = np.full(n, -1, dtype=int)
    chunk = max(1, _RAY_TRI_BUDGET // max(len(tri), 1))
    for s in range(0, n, chunk):
        o, d = origins[s:s + chunk], directions[s:s + chunk]
        v = centre[None, :, :] - o[:, None, :]
        along = np.einsum("rfk,rk->rf", v, d)
        perp2 = np.einsum("rfk,rfk->rf", v, v) - along ** 2
        # the line passes through the face's sphere, and the sphere is not behind the origin
        r_idx, f_idx = np.nonzero((perp2 <= radius2[None, :]) & (along >= -np.sqrt(radius2)[None, :]))
        if r_idx.size == 0:
            continue
        oo, dd = o[r_idx], d[r_idx]
        v0 = tri[f_idx, 0]
        e1, e2 = tri[f_idx, 1] - v0, tri[f_idx, 2] - v0
        p = np.cross(dd, e2)
        det = np.einsum("ik,ik->i", e1, p)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = oo - v0
        u = np.einsum("ik,ik->i", tvec, p) * inv
        qv = np.cross(tvec, e1)
        w = np.einsum("ik,ik->i", dd, qv) * inv
        t = np.einsum("ik,ik->i", e2, qv) * inv
        valid = ok & (u >= -1e-9) & (w >= -1e-9) & (u + w <= 1 + 1e-9) & (t > 1e-6)
        t = np.where(valid, t, np.inf)
        # nearest valid hit per ray: sort by (ray, t) and take the first of each ray
        order = np.lexsort((t, r_idx))
        r_sorted = r_idx[order]
        first = np.ones(order.size, dtype=bool)
        first[1:] = r_sorted[1:] != r_sorted[:-1]
        rows = r_sorted[first]
        best_t = t[order][first]
        best_f = f_idx[order][first]
        hit = np.isfinite(best_t)
        dist[s + rows[hit]] = best_t[hit]
        face[s + rows[hit]] = best_f[hit]
    return dist, face


def antipodal_pairs(obj: ObjectModel, hand: HandGeometry, settings: GraspSettings) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(centre, closing axis, width) of the deduplicated antipodal contact pairs near the CoM."""
    rng = np.random.default_rng(settings.seed)
    pts, normals = sample_surface(obj.mesh, settings.samples, rng)
    dist, face = first_hits(obj.mesh, pts - _RAY_EPS * normals, -normals)
    max_width = hand.max_opening_m - 2.0 * settings.clearance_m
    ok = np.isfinite(dist) & (dist >= settings.min_width_m) & (dist <= max_width)
    idx = np.flatnonzero(ok)
    far_normals = np.asarray(obj.mesh.face_normals)[face[idx]]
    anti = np.einsum("ij,ij->i", normals[idx], far_normals) < settings.antipodal_cos
    idx = idx[anti]
    width = dist[idx]
    axis = -normals[idx]  # from the sampled contact into the object: the closing direction
    centre = pts[idx] + axis * (width / 2.0)[:, None]
    com_d = np.linalg.norm(centre - obj.com_local, axis=1)
    near = com_d <= settings.max_com_distance_m
    centre, axis, width, com_d = centre[near], axis[near], width[near], com_d[near]
    # deterministic order: closest to the CoM first, ties by position
    order = np.lexsort((np.round(centre[:, 2], 6), np.round(centre[:, 1], 6), np.round(centre[:, 0], 6), np.round(com_d, 6)))
    kept = thin_out(order, centre, axis, settings, signed_axes=False)
    return [(centre[i], axis[i], float(width[i])) for i in kept]


def _candidate_frames(centre: np.ndarray, y: np.ndarray, settings: GraspSettings) -> list[np.ndarray]:
    u = perpendicular(y)
    w = np.cross(y, u)
    out = []
    for k in range(settings.rotations):
        th = 2.0 * np.pi * k / settings.rotations
        z = np.cos(th) * u + np.sin(th) * w
        for flip in ((1.0, -1.0) if settings.include_flipped else (1.0,)):
            yy = flip * y
            x = np.cross(yy, z)
            T = np.eye(4)
            T[:3, :3] = np.column_stack([x, yy, z])
            T[:3, 3] = centre
            out.append(T)
    return out


def compute_grasps(obj: ObjectModel, hand: HandGeometry, settings: GraspSettings) -> list[Grasp]:
    """Plan the grasps (no cache); see the module docstring for the steps. A rigid hand's grasps are
    surface contacts instead (:mod:`planner.grasping.contact_grasps`)."""
    if not hand.has_jaw:
        return compute_contact_grasps(obj, hand, settings)
    pairs = antipodal_pairs(obj, hand, settings)
    obodies = object_bodies(obj)
    oposes = np.array([b.local for b in obodies])  # the object sits at its own frame
    rows: list[tuple[np.ndarray, float, float]] = []
    for centre, axis, width in pairs:
        frames = np.array(_candidate_frames(centre, axis, settings))
        open_w = min(width + 2.0 * settings.clearance_m, hand.max_opening_m)
        hb = hand_bodies(hand, open_w)
        shape_T = np.array([b.local for b in hb])  # TCP -> shape
        poses_a = np.einsum("kij,sjl->ksil", frames, shape_T)
        hit = shapes_collide(hb, poses_a, obodies, oposes)
        rows.extend((T, width, open_w) for T, h in zip(frames, hit) if not h)
    com = obj.com_local
    keyed = sorted(rows, key=lambda r: (round(float(np.linalg.norm(r[0][:3, 3] - com)), 6), tuple(np.round(r[0][:3, :].ravel(), 6))))
    grasps = []
    for i, (T, width, open_w) in enumerate(keyed):
        grasps.append(Grasp(i, T, width, hand.jaw_value(width), open_w, hand.jaw_value(open_w),
                            float(np.linalg.norm(T[:3, 3] - com))))
    return grasps


# ---------------------------------------------------------------------------------------------
# cache


def cache_dir(explicit: str | Path | None = None) -> Path:
    """The grasp cache directory: explicit, else ``$REGRASP_CACHE_DIR``, else ``~/.cache/hrp-regrasp``."""
    if explicit is not None:
        return Path(explicit).expanduser()
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else DEFAULT_CACHE_DIR.expanduser()


def cache_key(obj: ObjectModel, hand: HandGeometry, settings: GraspSettings) -> str:
    h = hashlib.sha256()
    h.update(f"grasps/{GRASP_ALGORITHM_VERSION}/".encode())
    if not hand.has_jaw:
        h.update(f"contact/{CONTACT_ALGORITHM_VERSION}/".encode())
    h.update(obj.content_hash.encode())
    h.update(hand.signature())
    h.update(settings.key().encode())
    return h.hexdigest()


def _save(path: Path, key: str, grasps: list[Grasp]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "key": np.array(key),
        "T_obj_tcp": np.array([g.T_obj_tcp for g in grasps]).reshape(-1, 4, 4),
        "opening_m": np.array([g.opening_m for g in grasps]),
        "jaw_value": np.array([g.jaw_value for g in grasps]),
        "open_opening_m": np.array([g.open_opening_m for g in grasps]),
        "open_jaw_value": np.array([g.open_jaw_value for g in grasps]),
        "com_distance_m": np.array([g.com_distance_m for g in grasps]),
    }
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    os.close(fd)
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)  # atomic: concurrent workers never see half a file
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _load(path: Path, key: str) -> list[Grasp] | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != key:
                return None
            T, o, j, oo, oj, cd = (z[k] for k in ("T_obj_tcp", "opening_m", "jaw_value", "open_opening_m", "open_jaw_value", "com_distance_m"))
    except (OSError, KeyError, ValueError):
        return None  # unreadable or stale cache file: recompute
    return [Grasp(i, T[i].copy(), float(o[i]), float(j[i]), float(oo[i]), float(oj[i]), float(cd[i])) for i in range(len(o))]


def plan_grasps(
    obj: ObjectModel,
    robot: RobotModel,
    side: Side = "right",
    settings: GraspSettings | None = None,
    cache: bool = True,
    cache_directory: str | Path | None = None,
) -> GraspSet:
    """The grasps of ``obj`` for the ``side`` hand, from the disk cache when possible."""
    settings = settings or GraspSettings()
    hand = hand_geometry(robot, side)
    key = cache_key(obj, hand, settings)
    path = cache_dir(cache_directory) / f"grasps-{key[:40]}.npz"
    t0 = time.perf_counter()
    if cache and path.is_file():
        loaded = _load(path, key)
        if loaded is not None:
            return GraspSet(obj.content_hash, side, tuple(loaded), True, time.perf_counter() - t0, str(path))
    grasps = compute_grasps(obj, hand, settings)
    if cache:
        try:
            _save(path, key, grasps)
        except OSError:
            path = None  # type: ignore[assignment]  # read-only cache dir: still return the grasps
    return GraspSet(obj.content_hash, side, tuple(grasps), False, time.perf_counter() - t0, str(path) if cache and path else None)
