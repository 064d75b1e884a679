"""Placements: stable reference poses, table instantiation, start/goal validation messages."""

from __future__ import annotations

import numpy as np
import pytest

from planner.scene.placements import (
    PlacementError,
    PlacementSettings,
    check_resting,
    check_resting_pose,
    instantiate_placements,
    reference_poses,
)
from planner.transforms import make_transform, rot_x, rot_z


def test_reference_poses_are_stable(box_obj, drill_obj):
    for obj in (box_obj, drill_obj):
        refs = reference_poses(obj)
        assert refs
        for r in refs:
            assert r.stability_ratio >= 0.1
            T = r.T_ref
            pts = obj.mesh.vertices @ T[:3, :3].T + T[:3, 3]
            assert np.isclose(pts[:, 2].min(), 0.0, atol=1e-9)  # resting on z = 0
            com = T[:3, :3] @ obj.com_local + T[:3, 3]
            assert np.allclose(com[:2], 0.0, atol=1e-9) and np.isclose(com[2], r.com_height_m)
    # a 60 x 100 x 200 mm box rests on all six faces; upright on its 60 x 100 end the ratio is 0.3
    assert len(reference_poses(box_obj)) == 6
    # the drill lies on its sides and stands on its battery
    downs = [tuple(np.round(r.down_local, 3)) for r in reference_poses(drill_obj)]
    assert (0.0, 0.0, -1.0) in downs and (0.0, 1.0, 0.0) in downs


def test_stricter_ratio_drops_poses(box_obj):
    assert len(reference_poses(box_obj, PlacementSettings(stability_ratio=0.4))) < 6


def test_check_resting_messages(drill_obj, table_box):
    T = make_transform(p=[0.5, -0.2, 0.75])  # drill upright on its battery
    info = check_resting(drill_obj, T, [table_box], what="start pose")
    assert info.table == "table" and info.reference >= 0
    with pytest.raises(PlacementError, match="start pose is not resting on a table: lowest point 23 mm above table 'table'"):
        check_resting(drill_obj, make_transform(p=[0.5, -0.2, 0.773]), [table_box], what="start pose")
    with pytest.raises(PlacementError, match="sinks 10 mm into table 'table'"):
        check_resting(drill_obj, make_transform(p=[0.5, -0.2, 0.74]), [table_box])
    with pytest.raises(PlacementError, match="not over a table"):
        check_resting(drill_obj, make_transform(p=[2.0, 0.0, 0.75]), [table_box])
    tilted = make_transform(rot_x(0.4), [0.5, -0.2, 0.0])
    low = (drill_obj.mesh.vertices @ tilted[:3, :3].T)[:, 2].min()
    tilted[2, 3] = 0.75 - low  # touching the top with one edge only
    with pytest.raises(PlacementError, match="point or an edge"):
        check_resting(drill_obj, tilted, [table_box])


def test_instantiated_placements_include_start_goal_and_rest(drill_obj, table_box):
    start = make_transform(rot_x(-np.pi / 2), [0.4414, -0.307, 0.7785])
    goal = make_transform(rot_z(0.3), [0.45, 0.2, 0.75])
    pls = instantiate_placements(drill_obj, [table_box], start, goal, PlacementSettings(spot_spacing_m=0.2))
    assert pls[0].kind == "start" and np.allclose(pls[0].T_world_obj, start)
    assert pls[1].kind == "goal" and np.allclose(pls[1].T_world_obj, goal)
    assert pls[0].reference >= 0 and pls[1].reference >= 0
    spots = [p for p in pls if p.kind == "spot"]
    assert len(spots) > 20
    assert len({round(p.yaw, 6) for p in spots}) == 8
    for p in spots[:: max(1, len(spots) // 25)]:
        info = check_resting(drill_obj, p.T_world_obj, [table_box])
        assert info.reference == p.reference
        assert abs(info.gap_m) < 1e-9
    assert [p.id for p in pls] == list(range(len(pls)))


def test_region_limits_spots(drill_obj, table_box):
    start = make_transform(p=[0.5, -0.2, 0.75])
    s = PlacementSettings(spot_spacing_m=0.1, region=(0.4, 0.6, -0.3, 0.0))
    pls = instantiate_placements(drill_obj, [table_box], start, make_transform(p=[0.5, 0.2, 0.75]), s)
    for p in pls[2:]:
        c = p.T_world_obj[:3, :3] @ drill_obj.com_local + p.T_world_obj[:3, 3]
        assert p.kind == "spot" and -0.3 - 0.2 <= c[1] <= 0.0 + 0.2


def test_check_resting_pose_takes_wire_data(drill_obj):
    from schemas.scenario import BoxDef

    tables = [BoxDef(name="bench", pose=[0.6, 0.0, 0.73, 0, 0, 0, 1], size=[0.5, 1.4, 0.04])]
    assert check_resting_pose(drill_obj, [0.5, -0.2, 0.75, 0, 0, 0, 1], tables).table == "bench"
    with pytest.raises(PlacementError, match="goal pose is not resting on a table: lowest point 50 mm above table 'bench'"):
        check_resting_pose(drill_obj, [0.5, -0.2, 0.80, 0, 0, 0, 1], tables, what="goal pose")


def test_reference_poses_agree_with_trimesh(drill_obj):
    """Every reference pose is one of trimesh's quasi-static stable poses of the hull."""
    import trimesh

    Ts, _probs = trimesh.poses.compute_stable_poses(drill_obj.mesh, center_mass=drill_obj.com_local, n_samples=1, threshold=0.0)
    theirs = [T[:3, :3].T @ np.array([0.0, 0.0, -1.0]) for T in Ts]
    for r in reference_poses(drill_obj):
        assert max(float(r.down_local @ d) for d in theirs) > 1 - 1e-6
