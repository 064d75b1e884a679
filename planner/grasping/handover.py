"""Handover poses: the object floating in front of the chest, with pairs of compatible grasps.

At a handover both hands hold the object. A pair (right grasp, left grasp) is usable when
the two hands, each with its jaw open for the approach, do not collide with each other. That
test happens in the object frame, so it is done once per object and grasp set and shared
by every floating pose. Per pose, pairs are further kept only when each hand approaches from
the robot's side of the object (its approach axis does not point back toward the robot by
more than ``max_approach_angle_rad``), which prunes hopeless IK calls early.

Floating poses: positions in front of the chest (offsets from the stance's pelvis, moved with the
robot's shoulders where they sit elsewhere than on the robot the offsets were chosen for) x
"up" axes of the object (which object axis points up) x rolls about the vertical. The CoM,
not the object frame, is put at each position, so heavy objects stay close to the body.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.grasping.grasps import GraspSet
from planner.scene.bodies import shapes_collide
from planner.scene.collision import CollisionWorld
from planner.scene.hand import HandGeometry, hand_bodies
from planner.scene.objects import ObjectModel
from planner.transforms import frame_from_z, rot_z


class HandoverSettings(BaseModel):
    """Where and how the object floats for a handover (metres, radians, world axes)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    positions: tuple[tuple[float, float, float], ...] = Field(
        ((0.40, 0.0, 0.25), (0.35, 0.0, 0.35), (0.32, 0.0, 0.45)),
        description="CoM positions relative to the pelvis position (x forward, z up); heavy objects need "
        "them close (the CoM shift is mass x distance / total mass), and above the tables",
    )
    shoulders_m: tuple[float, float, float] = Field(
        (0.087, 0.0, 0.542),
        description="the shoulders' midpoint relative to the pelvis on the robot the positions were chosen for (the "
        "HRP-5P model): on a robot whose shoulders sit elsewhere the positions move with its shoulders (the planner "
        "passes the pelvis shifted by the difference, rounded to a micrometre)",
    )
    up_axes: tuple[tuple[float, float, float], ...] = Field(
        ((0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)),
        description="object axes pointed up",
    )
    rolls: int = Field(4, ge=1, le=72, description="yaw angles about the vertical per up axis")
    max_approach_angle_rad: float = Field(
        np.deg2rad(100.0), gt=0, le=np.pi, description="hand approach axis vs world +x (away from the robot)"
    )


@dataclass(frozen=True)
class HandoverPose:
    """A floating object pose and the usable (right grasp id, left grasp id) pairs there.

    ``pairs`` may be a thinned selection; ``all_pairs`` then holds every usable pair (None: ``pairs`` is every
    pair), so that a planner can still join the grasps a task starts and ends with (see
    :meth:`planner.regrasp.hand_config_planner.HandConfigPlanner.with_direct_handovers`).
    """

    id: int
    T_world_obj: np.ndarray
    pairs: np.ndarray  # (M, 2) int: right grasp id, left grasp id
    all_pairs: np.ndarray | None = None

    @property
    def every_pair(self) -> np.ndarray:
        """Every usable (right, left) pair at this pose, thinned or not."""
        return self.pairs if self.all_pairs is None else self.all_pairs


def compatible_pairs(right: GraspSet, left: GraspSet, hand_r: HandGeometry, hand_l: HandGeometry) -> np.ndarray:
    """(M, 2) pairs of grasp ids whose hands, jaws open, do not collide (object frame)."""
    nr, nl = len(right), len(left)
    if nr == 0 or nl == 0:
        return np.zeros((0, 2), dtype=int)

    def shape_poses(gs: GraspSet, hand: HandGeometry):
        bodies = None
        poses = []
        for g in gs.grasps:
            hb = hand_bodies(hand, g.open_opening_m)
            bodies = hb
            poses.append(np.einsum("ij,sjk->sik", g.T_obj_tcp, np.array([b.local for b in hb])))
        return bodies, np.array(poses)

    br, Pr = shape_poses(right, hand_r)
    bl, Pl = shape_poses(left, hand_l)
    ir, il = np.meshgrid(np.arange(nr), np.arange(nl), indexing="ij")
    ir, il = ir.ravel(), il.ravel()
    hit = np.zeros(ir.size, dtype=bool)
    chunk = 20000
    for s in range(0, ir.size, chunk):
        sl = slice(s, s + chunk)
        hit[sl] = shapes_collide(br, Pr[ir[sl]], bl, Pl[il[sl]])
    return np.column_stack([ir[~hit], il[~hit]]).astype(int)


def _up_rotation(axis: np.ndarray) -> np.ndarray:
    """A rotation taking the object's ``axis`` to world +z (deterministic about z)."""
    # rows: world axes in object coordinates -> maps object vectors to world
    return frame_from_z(np.asarray(axis, float) / np.linalg.norm(axis)).T.copy()


def floating_poses(obj: ObjectModel, pelvis_position: np.ndarray, settings: HandoverSettings | None = None) -> list[np.ndarray]:
    """World poses (4x4) of the object for handovers, deterministic order."""
    settings = settings or HandoverSettings()
    out = []
    for off in settings.positions:
        p = np.asarray(pelvis_position, float) + np.asarray(off, float)
        for axis in settings.up_axes:
            R_up = _up_rotation(np.asarray(axis, float))
            for k in range(settings.rolls):
                R = rot_z(2.0 * np.pi * k / settings.rolls) @ R_up
                T = np.eye(4)
                T[:3, :3] = R
                T[:3, 3] = p - R @ obj.com_local
                out.append(T)
    return out


def handover_poses(
    obj: ObjectModel,
    right: GraspSet,
    left: GraspSet,
    hand_r: HandGeometry,
    hand_l: HandGeometry,
    pelvis_position: np.ndarray,
    settings: HandoverSettings | None = None,
    world: CollisionWorld | None = None,
) -> list[HandoverPose]:
    """Floating poses with their usable grasp pairs; poses without any pair are dropped, and
    with a ``world`` so are poses where the object would touch a table or an obstacle."""
    settings = settings or HandoverSettings()
    pairs = compatible_pairs(right, left, hand_r, hand_l)
    zr = np.array([g.T_obj_tcp[:3, 2] for g in right.grasps]).reshape(-1, 3)
    zl = np.array([g.T_obj_tcp[:3, 2] for g in left.grasps]).reshape(-1, 3)
    cos_max = np.cos(settings.max_approach_angle_rad)
    out = []
    for T in floating_poses(obj, pelvis_position, settings):
        if world is not None and world.object_pose_clear(T) is not None:
            continue
        R = T[:3, :3]
        ok_r = (zr @ R.T)[:, 0] >= cos_max  # approach axis in the world vs +x
        ok_l = (zl @ R.T)[:, 0] >= cos_max
        keep = pairs[ok_r[pairs[:, 0]] & ok_l[pairs[:, 1]]] if len(pairs) else pairs
        if len(keep):
            out.append(HandoverPose(len(out), T, keep))
    return out
