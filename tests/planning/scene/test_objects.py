"""Object models: shapes, frames, CoM, hashes and mesh import errors."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from planner.scene.objects import (
    ObjectModelError,
    box_union_mesh,
    build_object,
    carrier_boxes,
    rectilinear_boxes,
)
from planner.scene.scenarios import DATA_DIR
from schemas.scenario import ObjectDef


def test_box_bar_cylinder_frames_and_com():
    box = build_object(ObjectDef(shape="box", size=[0.1, 0.2, 0.3], mass_kg=2))
    assert np.allclose(box.bounds, [[-0.05, -0.1, -0.15], [0.05, 0.1, 0.15]])
    assert np.allclose(box.com_local, 0)
    bar = build_object(ObjectDef(shape="bar", size=[0.05, 0.05, 0.4], mass_kg=5))
    assert np.allclose(bar.com_local, [0, 0, 0.2])  # the paper's one-legged CoM with no point mass
    assert np.isclose(bar.bounds[0, 2], 0.0)
    cyl = build_object(ObjectDef(shape="cylinder", size=[0.03, 0.2], mass_kg=1))
    assert np.allclose(cyl.extents, [0.06, 0.06, 0.2], atol=1e-6)
    for obj in (box, bar, cyl):
        assert obj.mesh.is_watertight and obj.mesh.volume > 0


def test_drill_dimensions_and_handle():
    drill = build_object(ObjectDef(shape="drill", mass_kg=1.3))
    assert np.allclose(drill.extents, [0.184, 0.057, 0.187], atol=1e-9)
    handle = drill.primitives[1]
    assert min(handle.dims[:2]) <= 0.070  # the jaw can close on the handle
    assert drill.mesh.is_watertight
    # the handle is near the CoM (a parallel jaw holds it with little torque)
    assert np.linalg.norm(handle.origin[:3, 3] - drill.com_local) < 0.06


def test_com_override_and_hash():
    a = build_object(ObjectDef(shape="box", size=[0.1, 0.1, 0.1], mass_kg=1))
    b = build_object(ObjectDef(shape="box", size=[0.1, 0.1, 0.1], mass_kg=1, com_local=[0.01, 0, 0]))
    c = build_object(ObjectDef(shape="box", size=[0.1, 0.1, 0.1], mass_kg=2))
    d = build_object(ObjectDef(shape="box", size=[0.1, 0.1, 0.1], mass_kg=1))
    assert np.allclose(b.com_local, [0.01, 0, 0])
    assert len({a.content_hash, b.content_hash, c.content_hash}) == 3
    assert a.content_hash == d.content_hash


def test_box_union_is_watertight_and_carrier_centroid():
    mesh = box_union_mesh(carrier_boxes())
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert np.allclose(mesh.center_mass, [0.15, 0.08, 0.15], atol=1e-9)
    mirrored = box_union_mesh(carrier_boxes(x_sign=-1))
    assert np.allclose(mirrored.center_mass, [-0.15, 0.08, 0.15], atol=1e-9)
    boxes = rectilinear_boxes(mesh)
    assert boxes is not None
    assert np.isclose(sum(np.prod(hi - lo) for lo, hi in boxes), mesh.volume)


def test_builtin_carrier_meshes_collide_as_boxes():
    for name, com in (("carrier_px.obj", [0.15, 0.08, 0.15]), ("carrier_nx.obj", [-0.15, 0.08, 0.15])):
        obj = build_object(ObjectDef(shape="mesh", mesh={"path": str(DATA_DIR / name)}, mass_kg=8.0))
        assert np.allclose(obj.com_local, com, atol=1e-6)
        assert obj.primitives and all(p.kind == "box" for p in obj.primitives)


def test_mesh_scale_and_relative_path(tmp_path):
    trimesh.creation.box((100.0, 60.0, 40.0)).export(tmp_path / "part.stl")
    obj = build_object(ObjectDef(shape="mesh", mesh={"path": "part.stl", "scale": 0.001}, mass_kg=1), base_dir=tmp_path)
    assert np.allclose(obj.extents, [0.1, 0.06, 0.04])
    with pytest.raises(ObjectModelError, match=r"part\.stl is 100\.0 m across.*scale: 0\.001"):
        build_object(ObjectDef(shape="mesh", mesh={"path": str(tmp_path / "part.stl")}, mass_kg=1))


def test_broken_mesh_names_the_file(tmp_path):
    bad = tmp_path / "broken.stl"
    bad.write_bytes(b"solid x\nfacet normal 0 0 1\n  outer loop\n   vertex 0 0\nendsolid\n")
    with pytest.raises(ObjectModelError, match="broken.stl"):
        build_object(ObjectDef(shape="mesh", mesh={"path": str(bad)}, mass_kg=1))
    missing = tmp_path / "missing.obj"
    with pytest.raises(ObjectModelError, match="missing.obj does not exist"):
        build_object(ObjectDef(shape="mesh", mesh={"path": str(missing)}, mass_kg=1))


def test_open_mesh_is_rejected(tmp_path):
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)  # remove one side
    path = tmp_path / "open.obj"
    open_box.export(path)
    with pytest.raises(ObjectModelError, match=r"open\.obj is not watertight: \d+ open edge"):
        build_object(ObjectDef(shape="mesh", mesh={"path": str(path)}, mass_kg=1))
