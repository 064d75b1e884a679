"""Grasps: antipodal, within the jaw, near the CoM, clear of the object, cached, deterministic."""

from __future__ import annotations

import fcl
import numpy as np

from planner.grasping.grasps import GraspSettings, first_hits, plan_grasps
from planner.scene.hand import hand_bodies, hand_geometry


def test_box_grasps_are_antipodal_and_fit_the_jaw(hrp5p, box_obj, box_grasps):
    hand = hand_geometry(hrp5p, "right")
    assert len(box_grasps) > 20
    for g in box_grasps.grasps:
        T = g.T_obj_tcp
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
        assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)
        y = T[:3, 1]
        # the only side of the 60 x 100 x 200 mm box that fits 82 mm - clearances is x (60 mm)
        assert np.allclose(np.abs(y), [1, 0, 0], atol=1e-9)
        assert np.isclose(g.opening_m, 0.06, atol=1e-9)
        assert g.opening_m <= hand.max_opening_m
        assert np.isclose(g.jaw_value, g.opening_m / hand.opening_per_unit)
        assert g.opening_m < g.open_opening_m <= hand.max_opening_m
        # both contacts lie on the surface along the closing axis
        c = T[:3, 3]
        for sgn in (-1, 1):
            contact = c + sgn * y * g.opening_m / 2
            assert np.isclose(abs(contact[0]), 0.03, atol=1e-9)


def test_contacts_are_on_opposite_faces_by_ray(box_obj, box_grasps):
    """Independent check: a ray from one contact along the closing axis leaves the box at the width."""
    poses = box_grasps.poses()
    y, c = poses[:, :3, 1], poses[:, :3, 3]
    widths = np.array([g.opening_m for g in box_grasps.grasps])
    start = c - y * (widths / 2 + 0.01)[:, None]  # outside the object, before the first jaw
    d_in, _ = first_hits(box_obj.mesh, start, y)
    d_out, _ = first_hits(box_obj.mesh, start + y * (d_in + 1e-6)[:, None], y)
    assert np.allclose(d_in, 0.01, atol=1e-6)
    assert np.allclose(d_out, widths, atol=1e-5)


def test_torque_filter(hrp5p, box_obj, box_grasps):
    assert max(g.com_distance_m for g in box_grasps.grasps) <= GraspSettings().max_com_distance_m + 1e-12
    tight = plan_grasps(box_obj, hrp5p, "right", GraspSettings(max_com_distance_m=0.02), cache=False)
    assert 0 < len(tight) < len(box_grasps)
    assert all(np.linalg.norm(g.T_obj_tcp[:3, 3] - box_obj.com_local) <= 0.02 + 1e-12 for g in tight.grasps)


def test_hand_clear_of_object_by_fcl(hrp5p, drill_obj, drill_grasps):
    """Independent check with fcl directly: the open hand at every grasp does not touch the drill."""
    hand = hand_geometry(hrp5p, "right")
    objs = [fcl.CollisionObject(fcl.Box(*p.dims), fcl.Transform(p.origin[:3, :3], p.origin[:3, 3])) for p in drill_obj.primitives]
    for g in drill_grasps["right"].grasps:
        for b in hand_bodies(hand, g.open_opening_m):
            T = g.T_obj_tcp @ b.local
            hb = fcl.CollisionObject(fcl.Box(*b.dims), fcl.Transform(T[:3, :3], T[:3, 3]))
            for o in objs:
                assert fcl.collide(hb, o, fcl.CollisionRequest(), fcl.CollisionResult()) == 0


def test_drill_grasped_on_its_handle_or_body(drill_grasps):
    widths = {round(g.opening_m, 4) for g in drill_grasps["right"].grasps}
    assert widths <= {0.045, 0.057}
    assert 0.045 in widths


def test_cache_hit_is_identical(hrp5p, box_obj, box_grasps, grasp_cache):
    again = plan_grasps(box_obj, hrp5p, "right", cache_directory=grasp_cache)
    assert again.from_cache and not box_grasps.from_cache
    assert len(again) == len(box_grasps)
    assert np.array_equal(again.poses(), box_grasps.poses())
    assert [g.opening_m for g in again.grasps] == [g.opening_m for g in box_grasps.grasps]
    # the left hand has the same geometry in its TCP frame: same cache entry
    left = plan_grasps(box_obj, hrp5p, "left", cache_directory=grasp_cache)
    assert left.from_cache and left.cache_file == again.cache_file


def test_env_cache_dir_and_determinism(hrp5p, box_obj, tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path))
    a = plan_grasps(box_obj, hrp5p, "right", GraspSettings(samples=200, seed=3))
    assert a.cache_file is not None and a.cache_file.startswith(str(tmp_path))
    b = plan_grasps(box_obj, hrp5p, "right", GraspSettings(samples=200, seed=3), cache=False)
    assert np.array_equal(a.poses(), b.poses())
    assert [g.id for g in a.grasps] == list(range(len(a)))
    d = [g.com_distance_m for g in a.grasps]
    assert d == sorted(d)


def test_corrupt_cache_file_is_recomputed(hrp5p, box_obj, tmp_path):
    a = plan_grasps(box_obj, hrp5p, "right", GraspSettings(samples=120), cache_directory=tmp_path)
    with open(a.cache_file, "wb") as fh:
        fh.write(b"not an npz")
    b = plan_grasps(box_obj, hrp5p, "right", GraspSettings(samples=120), cache_directory=tmp_path)
    assert not b.from_cache and np.array_equal(a.poses(), b.poses())


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from planner.scene.objects import build_object  # noqa: E402
from schemas.scenario import ObjectDef  # noqa: E402


@settings(max_examples=12, deadline=None)
@given(st.tuples(st.floats(0.02, 0.15), st.floats(0.02, 0.15), st.floats(0.02, 0.15)), st.integers(0, 10))
def test_box_grasp_properties(hrp5p, size, seed):
    """For any box: each grasp closes along a box axis whose size is the width, the width fits
    the jaw with its clearance, and the centre is within the torque filter."""
    obj = build_object(ObjectDef(shape="box", size=list(size), mass_kg=1.0))
    s = GraspSettings(samples=150, rotations=4, seed=seed)
    gs = plan_grasps(obj, hrp5p, "right", s, cache=False)
    hand = hand_geometry(hrp5p, "right")
    for g in gs.grasps:
        y = g.T_obj_tcp[:3, 1]
        axis = int(np.argmax(np.abs(y)))
        assert abs(abs(y[axis]) - 1.0) < 1e-9
        assert np.isclose(g.opening_m, size[axis], atol=1e-9)
        assert s.min_width_m <= g.opening_m <= hand.max_opening_m - 2 * s.clearance_m
        assert g.com_distance_m <= s.max_com_distance_m + 1e-12
    if min(size) > hand.max_opening_m - 2 * s.clearance_m:
        assert len(gs) == 0
