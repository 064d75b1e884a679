"""Grasps of a rigid hand: the TCP on the object's surface, approaching along the inward normal.

A rigid hand has no jaw; the held object attaches at its TCP (a fixed mount, a magnet or a
suction pad: the spec says the hand is rigid, the planner does not model how it sticks). A grasp
is therefore one contact point and an approach direction, and needs no antipodal pair or width.

Recipe (deterministic, the jaw grasps' settings reused where they mean the same):

1. sample surface points, area-weighted, with a seeded ``numpy.random.Generator``;
2. keep the points whose inward normal line passes within ``max_com_distance_m`` of the CoM (the
   hand pushes toward the CoM, so the held weight's moment about the contact stays small), and
   thin out near-duplicates (``dedupe_position_m``, ``dedupe_angle_rad``), those whose normal line
   passes closest to the CoM first (so every face's middle comes before any face's edge), at most
   ``max_pairs`` contacts;
3. per contact, the TCP frame has z along the inward normal (out of the palm, into the object) and
   its x axis turned ``rotations`` times about z;
4. drop hand poses where the hand, moved back by ``clearance_m`` along its approach, still collides
   with the object (touching at the contact is the grasp; reaching into the object is not).

Opening and jaw values are 0: nothing opens.
"""

from __future__ import annotations

import numpy as np

from planner.grasping.grasp_model import Grasp, GraspSettings, sample_surface, thin_out
from planner.scene.bodies import object_bodies, shapes_collide
from planner.scene.hand import HandGeometry, hand_bodies
from planner.scene.objects import ObjectModel
from planner.transforms import perpendicular

#: Bump when the recipe changes, so old cache files are not reused.
CONTACT_ALGORITHM_VERSION = 1


def surface_contacts(obj: ObjectModel, settings: GraspSettings) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(point, inward normal, distance to the CoM) of the deduplicated contacts facing the CoM, those whose
    normal line passes closest to it first."""
    rng = np.random.default_rng(settings.seed)
    pts, normals = sample_surface(obj.mesh, settings.samples, rng)
    inward = -normals
    to_com = obj.com_local - pts
    along = np.einsum("ij,ij->i", to_com, inward)
    off_line = np.linalg.norm(to_com - along[:, None] * inward, axis=1)
    facing = (along > 0.0) & (off_line <= settings.max_com_distance_m)
    pts, inward, off_line = pts[facing], inward[facing], off_line[facing]
    com_d = np.linalg.norm(obj.com_local - pts, axis=1)
    order = np.lexsort((np.round(pts[:, 2], 6), np.round(pts[:, 1], 6), np.round(pts[:, 0], 6), np.round(com_d, 6),
                        np.round(off_line, 6)))
    kept = thin_out(order, pts, inward, settings, signed_axes=True)
    return [(pts[i], inward[i], float(com_d[i])) for i in kept]


def _contact_frames(point: np.ndarray, z: np.ndarray, rotations: int) -> np.ndarray:
    """(rotations, 4, 4) TCP frames at ``point`` with z along ``z``, x turned about it."""
    u = perpendicular(z)
    w = np.cross(z, u)
    out = np.repeat(np.eye(4)[None], rotations, axis=0)
    for k in range(rotations):
        th = 2.0 * np.pi * k / rotations
        x = np.cos(th) * u + np.sin(th) * w
        out[k, :3, :3] = np.column_stack([x, np.cross(z, x), z])
        out[k, :3, 3] = point
    return out


def compute_contact_grasps(obj: ObjectModel, hand: HandGeometry, settings: GraspSettings) -> list[Grasp]:
    """The rigid hand's grasps of ``obj`` (no cache); see the module docstring for the steps."""
    obodies = object_bodies(obj)
    oposes = np.array([b.local for b in obodies])
    hb = hand_bodies(hand, 0.0)
    back_off = np.eye(4)
    back_off[2, 3] = -settings.clearance_m
    shape_T = np.array([back_off @ b.local for b in hb])  # TCP -> shape, the hand moved back by the clearance
    rows: list[tuple[np.ndarray, float]] = []
    for point, inward, com_d in surface_contacts(obj, settings):
        frames = _contact_frames(point, inward, settings.rotations)
        hit = shapes_collide(hb, np.einsum("kij,sjl->ksil", frames, shape_T), obodies, oposes)
        rows.extend((T, com_d) for T, h in zip(frames, hit) if not h)
    return [Grasp(i, T, 0.0, 0.0, 0.0, 0.0, com_d) for i, (T, com_d) in enumerate(rows)]
