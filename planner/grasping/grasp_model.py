"""What a grasp is and how grasps are planned, shared by the jaw's antipodal grasps
(:mod:`planner.grasping.grasps`) and a rigid hand's contact grasps (:mod:`planner.grasping.contact_grasps`):
the settings, the grasp record, and the surface sampling and thinning both recipes use."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field

from planner.transforms import inverse


class GraspSettings(BaseModel):
    """Parameters of grasp planning (SI units)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    samples: int = Field(600, ge=10, le=200_000, description="surface points sampled")
    antipodal_cos: float = Field(-0.95, ge=-1.0, le=0.0, description="normals' dot product must be below this")
    max_com_distance_m: float = Field(0.06, gt=0, description="torque filter: grasp centre within this of the CoM")
    rotations: int = Field(12, ge=1, le=360, description="approach directions about the closing axis")
    include_flipped: bool = Field(True, description="also the hand turned half a turn about its approach axis")
    clearance_m: float = Field(0.004, ge=0, description="jaw opening beyond the width, per side, while approaching")
    min_width_m: float = Field(0.005, gt=0, description="thinner parts are not grasped")
    dedupe_position_m: float = Field(0.015, ge=0, description="contact pairs whose centres are closer are merged")
    dedupe_angle_rad: float = Field(0.15, ge=0, description="... and whose closing axes differ by less")
    max_pairs: int = Field(64, ge=1, description="contact pairs kept (closest to the CoM first), bounding time and count")
    seed: int = Field(0, ge=0)

    def key(self) -> str:
        return self.model_dump_json()


@dataclass(frozen=True)
class Grasp:
    """One grasp in the object frame."""

    id: int
    T_obj_tcp: np.ndarray  # 4x4, TCP frame in the object frame
    opening_m: float  # jaw opening closed on the object (= the object's width there)
    jaw_value: float  # gripper joint value for ``opening_m``
    open_opening_m: float  # jaw opening while approaching and releasing
    open_jaw_value: float
    com_distance_m: float  # grasp centre to object CoM

    @property
    def T_tcp_obj(self) -> np.ndarray:
        """The object frame in the TCP frame (what the holding hand carries)."""
        return inverse(self.T_obj_tcp)


def sample_surface(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted surface points and their outward face normals."""
    areas = np.asarray(mesh.area_faces, dtype=float)
    faces = rng.choice(len(areas), size=count, p=areas / areas.sum())
    tri = np.asarray(mesh.triangles)[faces]
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    pts = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    return pts, np.asarray(mesh.face_normals)[faces]


def thin_out(order: np.ndarray, points: np.ndarray, axes: np.ndarray, settings: GraspSettings, *,
             signed_axes: bool) -> list[int]:
    """The indices, in ``order``, of the points kept when each one closer than ``dedupe_position_m`` to a kept one
    with an axis within ``dedupe_angle_rad`` of its axis is dropped, at most ``max_pairs``. ``signed_axes``: a
    contact's approach and its reverse differ (else a closing axis and its reverse are the same)."""
    kept: list[int] = []
    cos_dup = np.cos(settings.dedupe_angle_rad)
    for i in order:
        if kept:
            align = axes[kept] @ axes[i]
            near = np.linalg.norm(points[kept] - points[i], axis=1) < settings.dedupe_position_m
            if (near & ((align if signed_axes else np.abs(align)) > cos_dup)).any():
                continue
        kept.append(int(i))
        if len(kept) >= settings.max_pairs:
            break
    return kept
