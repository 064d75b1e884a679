"""Object models: geometry, mass and CoM of the thing the robot moves.

An :class:`ObjectModel` is built once from a scenario's :class:`schemas.scenario.ObjectDef`
and never changes; grasp and placement caches key on its ``content_hash``.

Frame conventions (all lengths in metres):

- ``box`` ``[x, y, z]``: frame at the box centre, axes along the edges.
- ``cylinder`` ``[radius, height]``: frame at the centre, axis along z.
- ``bar`` ``[x, y, z]``: a long box whose frame sits at the centre of its bottom end face
  (z from 0 to the length), so a bar stood on its end has its frame on the table and its
  centre ``z/2`` above it, like the paper's one-legged object (CoM (0, 0, 200) mm).
- ``drill``: a cordless-drill-like union of boxes (battery, handle, motor body), frame at the
  centre of the battery's bottom face, chuck along +x, z up. Optional ``size`` scales the
  default bounding box (184 x 57 x 187 mm, the YCB power drill's). The handle is 45 mm
  thick, so the 82 mm jaw closes on it.
- ``mesh``: an STL/OBJ file in its own coordinates (times ``scale``); it must be watertight.

``com_local`` overrides the centre of mass as a point mass (the planner only needs the
total mass and the CoM); without it the CoM is the geometric centroid of the solid.
"""

from __future__ import annotations

import hashlib
import itertools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from planner.errors import ObjectModelError
from schemas.scenario import ObjectDef

#: Default drill bounding box (YCB power drill, 184 x 57 x 187 mm).
DRILL_SIZE_M = (0.184, 0.057, 0.187)
#: Meshes bigger than this are almost surely in millimetres.
MAX_OBJECT_EXTENT_M = 3.0
#: Facets of a cylinder mesh (collision uses fcl's exact cylinder).
CYLINDER_SECTIONS = 32


@dataclass(frozen=True)
class ObjectPrimitive:
    """A collision primitive of an object, in the object frame."""

    kind: str  # "box" (dims = full sizes x, y, z) | "cylinder" (dims = radius, height)
    dims: tuple[float, ...]
    origin: np.ndarray = field(repr=False)  # 4x4 pose of the primitive centre in the object frame

    def half_extents(self) -> np.ndarray:
        """Half sizes of the primitive's own bounding box (for the oriented-box broadphase)."""
        if self.kind == "box":
            return np.asarray(self.dims, dtype=float) / 2.0
        r, h = self.dims
        return np.array([r, r, h / 2.0])


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """What the object is: immutable, hashed for caches.

    ``primitives`` describe the collision geometry exactly when the object is made of
    boxes and cylinders; a ``mesh`` object has none and collides through its triangles.
    """

    name: str
    shape: str
    mesh: trimesh.Trimesh = field(repr=False)
    mass_kg: float
    com_local: np.ndarray
    content_hash: str
    primitives: tuple[ObjectPrimitive, ...] = field(default=(), repr=False)
    source: str = ""

    @property
    def extents(self) -> np.ndarray:
        return np.asarray(self.mesh.extents, dtype=float)

    @property
    def bounds(self) -> np.ndarray:
        return np.asarray(self.mesh.bounds, dtype=float)


def box_union_mesh(boxes: list[tuple[np.ndarray, np.ndarray]]) -> trimesh.Trimesh:
    """Watertight surface of a union of axis-aligned boxes ``(lo, hi)``.

    The boxes are cut on the grid of all their face coordinates; a cell face is emitted
    where a filled cell meets an empty one. Faces shared by two touching boxes therefore
    vanish, so grasp sampling never lands on an internal face, and no boolean engine is
    needed.
    """
    los = np.array([np.asarray(b[0], float) for b in boxes])
    his = np.array([np.asarray(b[1], float) for b in boxes])
    if np.any(his <= los):
        raise ObjectModelError(f"degenerate box in union: lo {los.tolist()} hi {his.tolist()}")
    grids = [np.unique(np.round(np.concatenate([los[:, a], his[:, a]]), 12)) for a in range(3)]
    centres = [0.5 * (g[:-1] + g[1:]) for g in grids]
    cx, cy, cz = np.meshgrid(*centres, indexing="ij")
    pts = np.stack([cx, cy, cz], axis=-1)
    filled = np.zeros(cx.shape, dtype=bool)
    for lo, hi in zip(los, his):
        filled |= np.all((pts > lo) & (pts < hi), axis=-1)
    padded = np.pad(filled, 1)
    verts: list[np.ndarray] = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        lo_side = np.take(padded, range(0, padded.shape[a] - 1), axis=a)
        hi_side = np.take(padded, range(1, padded.shape[a]), axis=a)
        # trim the padding on the two other axes
        sl = [slice(1, -1)] * 3
        sl[a] = slice(None)
        lo_side, hi_side = lo_side[tuple(sl)], hi_side[tuple(sl)]
        for sign, mask in ((1.0, lo_side & ~hi_side), (-1.0, ~lo_side & hi_side)):
            for idx in np.argwhere(mask):
                ia, ib, ic = idx[a], idx[b], idx[c]
                quad = []
                corners = [(0, 0), (1, 0), (1, 1), (0, 1)] if sign > 0 else [(0, 0), (0, 1), (1, 1), (1, 0)]
                for db, dc in corners:
                    v = np.empty(3)
                    v[a] = grids[a][ia]
                    v[b] = grids[b][ib + db]
                    v[c] = grids[c][ic + dc]
                    quad.append(v)
                verts.extend([quad[0], quad[1], quad[2], quad[0], quad[2], quad[3]])
    V = np.array(verts)
    F = np.arange(len(V)).reshape(-1, 3)
    mesh = trimesh.Trimesh(vertices=V, faces=F, process=True)
    mesh.merge_vertices()
    return mesh


def _box_primitive(lo: np.ndarray, hi: np.ndarray) -> ObjectPrimitive:
    origin = np.eye(4)
    origin[:3, 3] = 0.5 * (np.asarray(lo) + np.asarray(hi))
    return ObjectPrimitive("box", tuple(float(v) for v in np.asarray(hi) - np.asarray(lo)), origin)


def drill_boxes(size: tuple[float, float, float] = DRILL_SIZE_M) -> list[tuple[np.ndarray, np.ndarray]]:
    """Battery, handle and motor body of the drill-like object, scaled to ``size``.

    Proportions of a cordless drill: a 50 mm battery block under a 45 x 45 mm handle
    topped by the motor body running forward to the chuck. The handle sits near the
    centroid (about 35 mm away), so a jaw on the handle holds the drill with little torque.
    """
    sx, sy, sz = (s / d for s, d in zip(size, DRILL_SIZE_M))
    half_y = 0.0285 * sy
    handle_half_y = 0.0225 * sy
    mm = 1e-3
    battery = (np.array([-60 * mm * sx, -half_y, 0.0]), np.array([60 * mm * sx, half_y, 50 * mm * sz]))
    handle = (np.array([-45 * mm * sx, -handle_half_y, 50 * mm * sz]), np.array([0.0, handle_half_y, 130 * mm * sz]))
    body = (np.array([-70 * mm * sx, -half_y, 130 * mm * sz]), np.array([114 * mm * sx, half_y, 187 * mm * sz]))
    return [battery, handle, body]


def carrier_boxes(
    size: tuple[float, float, float] = (0.30, 0.16, 0.30), plate_m: float = 0.03, handle_m: float = 0.05, x_sign: float = 1.0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """A carrier: two end plates joined by a square handle bar through the middle.

    The built-in scenarios' stand-in for the paper's heavy box: its bounding box is the
    paper's 300 x 160 x 300 mm box with the frame at a corner, so the CoM sits at the
    paper's offset (150, 80, 150) mm (``x_sign=-1`` mirrors it to (-150, 80, 150) mm), and
    the 50 mm handle through that CoM is what the 82 mm jaw holds.
    """
    sx, sy, sz = size
    lo_x, hi_x = (0.0, sx) if x_sign > 0 else (-sx, 0.0)
    cy, cz, hh = sy / 2.0, sz / 2.0, handle_m / 2.0
    return [
        (np.array([lo_x, 0.0, 0.0]), np.array([lo_x + plate_m, sy, sz])),
        (np.array([hi_x - plate_m, 0.0, 0.0]), np.array([hi_x, sy, sz])),
        (np.array([lo_x + plate_m, cy - hh, cz - hh]), np.array([hi_x - plate_m, cy + hh, cz + hh])),
    ]


def _load_mesh_file(path: Path, scale: float) -> trimesh.Trimesh:
    if not path.is_file():
        raise ObjectModelError(f"mesh file {path} does not exist")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise ObjectModelError(f"mesh file {path} cannot be read: {type(exc).__name__}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ObjectModelError(f"mesh file {path} holds no triangles (empty or unreadable)")
    mesh = loaded.copy()
    mesh.apply_scale(scale)
    mesh.merge_vertices()
    mesh.remove_unreferenced_vertices()
    if not np.all(np.isfinite(mesh.vertices)):
        raise ObjectModelError(f"mesh file {path} has non-finite vertex coordinates")
    if not mesh.is_watertight:
        edges = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
        raise ObjectModelError(
            f"mesh file {path} is not watertight: {len(edges)} open edge(s); the planner needs a closed "
            f"solid for its volume, CoM and stable poses (repair it, e.g. close the holes, and retry)"
        )
    if not mesh.is_winding_consistent:
        raise ObjectModelError(f"mesh file {path} has inconsistent face winding (some normals point inwards)")
    if mesh.volume < 0:
        mesh.invert()
    if mesh.volume <= 1e-12:
        raise ObjectModelError(f"mesh file {path} encloses no volume ({mesh.volume:.3g} m^3)")
    extent = float(np.max(mesh.extents))
    if extent > MAX_OBJECT_EXTENT_M:
        raise ObjectModelError(
            f"mesh file {path} is {extent:.1f} m across after scale {scale}; lengths are metres "
            f"(a file in millimetres needs scale: 0.001)"
        )
    return mesh


def _merge_cells(filled: np.ndarray, grids: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Greedy merge of filled grid cells into boxes: runs along axis 0, then 1, then 2."""
    shape = filled.shape
    boxes: list[tuple[np.ndarray, np.ndarray]] = []
    used = np.zeros(shape, dtype=bool)
    for i, j, k in np.argwhere(filled):
        if used[i, j, k]:
            continue
        i2 = i
        while i2 + 1 < shape[0] and filled[i2 + 1, j, k] and not used[i2 + 1, j, k]:
            i2 += 1
        j2 = j
        while j2 + 1 < shape[1] and np.all(filled[i:i2 + 1, j2 + 1, k] & ~used[i:i2 + 1, j2 + 1, k]):
            j2 += 1
        k2 = k
        while k2 + 1 < shape[2] and np.all(filled[i:i2 + 1, j:j2 + 1, k2 + 1] & ~used[i:i2 + 1, j:j2 + 1, k2 + 1]):
            k2 += 1
        used[i:i2 + 1, j:j2 + 1, k:k2 + 1] = True
        boxes.append((np.array([grids[0][i], grids[1][j], grids[2][k]]), np.array([grids[0][i2 + 1], grids[1][j2 + 1], grids[2][k2 + 1]])))
    return boxes


def rectilinear_boxes(mesh: trimesh.Trimesh, max_cells: int = 4096) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Exact decomposition of a mesh whose faces are all axis-aligned into boxes, else None.

    Such meshes (unions of boxes, like the built-in carrier) then collide as boxes, which the
    collision checker decides exactly and fast, instead of as a triangle soup. The grid of the
    vertex coordinates is filled by a ray-parity inside test at each cell centre, then runs of
    filled cells are merged along x, y and z.
    """
    normals = np.asarray(mesh.face_normals)
    if not np.all(np.isclose(np.abs(normals).max(axis=1), 1.0, atol=1e-9)):
        return None
    grids = [np.unique(np.round(np.asarray(mesh.vertices)[:, a], 9)) for a in range(3)]
    shape = tuple(len(g) - 1 for g in grids)
    if min(shape) < 1 or int(np.prod(shape)) > max_cells:
        return None
    centres = [0.5 * (g[:-1] + g[1:]) for g in grids]
    pts = np.stack(np.meshgrid(*centres, indexing="ij"), axis=-1).reshape(-1, 3)
    # nudge off the cell centre, which lies on the diagonal of a face's two triangles
    sizes = np.stack(np.meshgrid(*[np.diff(g) for g in grids], indexing="ij"), axis=-1).reshape(-1, 3)
    pts = pts + sizes * np.array([0.0, 0.0137, 0.0291])
    # parity of +x ray crossings with the faces perpendicular to x
    tri = np.asarray(mesh.triangles)
    xf = np.abs(normals[:, 0]) > 0.5
    tx = tri[xf]
    lo_yz, hi_yz = tx[:, :, 1:].min(axis=1), tx[:, :, 1:].max(axis=1)
    crossings = np.zeros(len(pts), dtype=int)
    for f in range(len(tx)):
        a, b, c = tx[f]
        # point-in-triangle in the yz plane (barycentric), for points left of the face
        v0, v1 = b[1:] - a[1:], c[1:] - a[1:]
        w = pts[:, 1:] - a[1:]
        den = v0[0] * v1[1] - v1[0] * v0[1]
        if abs(den) < 1e-18:
            continue
        s = (w[:, 0] * v1[1] - v1[0] * w[:, 1]) / den
        t = (v0[0] * w[:, 1] - w[:, 0] * v0[1]) / den
        inside = (s >= 0) & (t >= 0) & (s + t <= 1) & (pts[:, 0] < a[0])
        inside &= np.all((pts[:, 1:] >= lo_yz[f]) & (pts[:, 1:] <= hi_yz[f]), axis=1)
        crossings += inside
    filled = (crossings % 2 == 1).reshape(shape)
    # greedy merge in each of the 6 axis orders; keep the fewest boxes (fewer collision pairs)
    boxes: list[tuple[np.ndarray, np.ndarray]] = []
    for order in itertools.permutations(range(3)):
        cand = _merge_cells(np.transpose(filled, order), [grids[a] for a in order])
        inv = np.argsort(order)
        cand = [(lo[inv], hi[inv]) for lo, hi in cand]
        if not boxes or len(cand) < len(boxes):
            boxes = cand
    total = sum(float(np.prod(hi - lo)) for lo, hi in boxes)
    if not boxes or abs(total - float(mesh.volume)) > 1e-6 * max(1.0, abs(float(mesh.volume))) + 1e-12:
        return None  # the decomposition does not reproduce the solid: keep the triangles
    return boxes


def _content_hash(shape: str, mesh: trimesh.Trimesh, prims: tuple[ObjectPrimitive, ...], mass: float, com: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(shape.encode())
    h.update((np.round(np.asarray(mesh.vertices, dtype=float), 9) + 0.0).tobytes())
    h.update(np.asarray(mesh.faces, dtype=np.int64).tobytes())
    for p in prims:
        h.update(p.kind.encode())
        h.update((np.round(np.asarray(p.dims, float), 9) + 0.0).tobytes())
        h.update((np.round(p.origin, 9) + 0.0).tobytes())
    h.update((np.round(np.array([mass, *com], dtype=float), 9) + 0.0).tobytes())
    return h.hexdigest()


def build_object(definition: ObjectDef, base_dir: Path | None = None) -> ObjectModel:
    """Build an :class:`ObjectModel` from a scenario's object definition.

    ``base_dir`` resolves a relative mesh path (the scenario file's directory).
    """
    shape = definition.shape
    prims: tuple[ObjectPrimitive, ...] = ()
    source = ""
    if shape == "box" or shape == "bar":
        sx, sy, sz = (float(v) for v in definition.size)  # type: ignore[union-attr]
        if shape == "box":
            lo, hi = np.array([-sx, -sy, -sz]) / 2, np.array([sx, sy, sz]) / 2
        else:
            lo, hi = np.array([-sx / 2, -sy / 2, 0.0]), np.array([sx / 2, sy / 2, sz])
        prims = (_box_primitive(lo, hi),)
        mesh = box_union_mesh([(lo, hi)])
    elif shape == "cylinder":
        r, h = (float(v) for v in definition.size)  # type: ignore[union-attr]
        mesh = trimesh.creation.cylinder(radius=r, height=h, sections=CYLINDER_SECTIONS)
        prims = (ObjectPrimitive("cylinder", (r, h), np.eye(4)),)
    elif shape == "drill":
        size = tuple(float(v) for v in definition.size) if definition.size else DRILL_SIZE_M
        boxes = drill_boxes(size)  # type: ignore[arg-type]
        prims = tuple(_box_primitive(lo, hi) for lo, hi in boxes)
        mesh = box_union_mesh(boxes)
    elif shape == "mesh":
        assert definition.mesh is not None
        if definition.mesh.path is None:  # a registered name not yet resolved (planner.scene.meshes)
            from planner.scene.meshes import mesh_file

            definition.mesh.path = str(mesh_file(definition.mesh.name or ""))
        path = Path(definition.mesh.path)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        mesh = _load_mesh_file(path, float(definition.mesh.scale))
        source = str(path)
        boxes = rectilinear_boxes(mesh)
        if boxes is not None:
            prims = tuple(_box_primitive(lo, hi) for lo, hi in boxes)
    else:  # pragma: no cover - the schema's Literal rules this out
        raise ObjectModelError(f"unknown object shape {shape!r}")
    if not mesh.is_watertight:  # pragma: no cover - generated meshes are closed by construction
        raise ObjectModelError(f"object {definition.name!r}: generated {shape} mesh is not watertight")
    com = np.array(definition.com_local, dtype=float) if definition.com_local is not None else np.array(mesh.center_mass, dtype=float)
    mass = float(definition.mass_kg)
    com.setflags(write=False)
    return ObjectModel(
        name=definition.name,
        shape=shape,
        mesh=mesh,
        mass_kg=mass,
        com_local=com,
        content_hash=_content_hash(shape, mesh, prims, mass, com),
        primitives=prims,
        source=source,
    )
