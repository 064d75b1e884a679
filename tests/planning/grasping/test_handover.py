"""Handover poses: floating in front of the chest, grasp pairs whose hands do not collide."""

from __future__ import annotations

import fcl
import numpy as np

from planner.grasping.handover import (
    HandoverSettings,
    compatible_pairs,
    floating_poses,
    handover_poses,
)
from planner.scene.hand import hand_bodies, hand_geometry


def _fcl_hands_collide(hrp5p, gr, gl) -> bool:
    objs = []
    for side, g in (("right", gr), ("left", gl)):
        group = []
        for b in hand_bodies(hand_geometry(hrp5p, side), g.open_opening_m):
            T = g.T_obj_tcp @ b.local
            group.append(fcl.CollisionObject(fcl.Box(*b.dims), fcl.Transform(T[:3, :3], T[:3, 3])))
        objs.append(group)
    return any(fcl.collide(a, b, fcl.CollisionRequest(), fcl.CollisionResult()) > 0 for a in objs[0] for b in objs[1])


def test_compatible_pairs_match_fcl(hrp5p, drill_grasps):
    right, left = drill_grasps["right"], drill_grasps["left"]
    pairs = compatible_pairs(right, left, hand_geometry(hrp5p, "right"), hand_geometry(hrp5p, "left"))
    assert 0 < len(pairs) < len(right) * len(left)
    ok = {tuple(p) for p in pairs.tolist()}
    rng = np.random.default_rng(0)
    for i, j in zip(rng.integers(0, len(right), 150), rng.integers(0, len(left), 150)):
        assert ((int(i), int(j)) in ok) == (not _fcl_hands_collide(hrp5p, right[int(i)], left[int(j)]))


def test_floating_poses_put_the_com_in_front_of_the_chest(drill_obj):
    s = HandoverSettings(positions=((0.4, 0.0, 0.25),), rolls=2)
    poses = floating_poses(drill_obj, np.array([0.0, 0.0, 0.8]), s)
    assert len(poses) == len(s.up_axes) * 2
    for T in poses:
        com = T[:3, :3] @ drill_obj.com_local + T[:3, 3]
        assert np.allclose(com, [0.4, 0.0, 1.05])
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)


def test_handover_poses_filter_approach(hrp5p, drill_obj, drill_grasps):
    hr, hl = hand_geometry(hrp5p, "right"), hand_geometry(hrp5p, "left")
    poses = handover_poses(drill_obj, drill_grasps["right"], drill_grasps["left"], hr, hl, np.array([0, 0, 0.8]))
    assert poses and [p.id for p in poses] == list(range(len(poses)))
    limit = np.cos(HandoverSettings().max_approach_angle_rad)
    for p in poses:
        R = p.T_world_obj[:3, :3]
        for i, j in p.pairs[:50]:
            assert (R @ drill_grasps["right"][i].T_obj_tcp[:3, 2])[0] >= limit - 1e-12
            assert (R @ drill_grasps["left"][j].T_obj_tcp[:3, 2])[0] >= limit - 1e-12


def test_world_drops_poses_inside_tables(hrp5p, drill_obj, drill_grasps):
    from planner.scene.bodies import EnvBox
    from planner.scene.collision import CollisionWorld
    from planner.transforms import make_transform

    hr, hl = hand_geometry(hrp5p, "right"), hand_geometry(hrp5p, "left")
    s = HandoverSettings(positions=((0.40, 0.0, 0.25),), rolls=2)
    pelvis = np.array([0.0, 0.0, 0.8])
    free = handover_poses(drill_obj, drill_grasps["right"], drill_grasps["left"], hr, hl, pelvis, s)
    # a slab right at the handover height swallows every floating pose
    slab = EnvBox("slab", make_transform(p=[0.6, 0.0, 1.05]), (0.6, 1.0, 0.06))
    world = CollisionWorld(hrp5p, [slab], drill_obj)
    blocked = handover_poses(drill_obj, drill_grasps["right"], drill_grasps["left"], hr, hl, pelvis, s, world=world)
    assert free and not blocked
