"""Stances: where the feet are and how the pelvis stands (docs/contract.md section 2).

A stance is data. The four built-ins are computed from the robot spec; a user can
write more in YAML with the same fields.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from .common import Finite, Pose7, StrictModel, Vec2

SUPPORT_CENTRE = "support-centre"


class FootPlacement(StrictModel):
    frame: str = Field(description="sole frame, e.g. l_sole or r_sole")
    in_contact: bool = Field(True, description="a raised foot does not count for the support polygon")
    pose: Pose7 = Field(description="sole frame in the world [x, y, z, qx, qy, qz, qw]")


class StanceDef(StrictModel):
    name: str
    feet: list[FootPlacement] = Field(min_length=1, max_length=8)
    pelvis_height_m: Finite | None = Field(None, gt=0.2, lt=2.0, description="pelvis origin above the ground; default: the robot's upright height")
    pelvis_offset: Vec2 = Field(default_factory=lambda: [0.0, 0.0], description="pelvis origin x, y in the world")
    com_over: str | None = Field(
        None,
        description="solve the pelvis x, y so that the robot CoM stands above this sole's centre (one-legged stances), "
        "or above the support polygon's centroid with 'support-centre' (what a balance controller does)",
    )

    @model_validator(mode="after")
    def _check(self) -> "StanceDef":
        frames = [f.frame for f in self.feet]
        if len(set(frames)) != len(frames):
            raise ValueError(f"feet name a frame twice: {frames}")
        if not any(f.in_contact for f in self.feet):
            raise ValueError("at least one foot must be in contact with the ground")
        if self.com_over is not None and self.com_over != SUPPORT_CENTRE and self.com_over not in frames:
            raise ValueError(f"com_over {self.com_over!r} is neither {SUPPORT_CENTRE!r} nor one of the feet {frames}")
        return self


class StanceResult(StrictModel):
    """A solved stance as it appears in plan and survey files."""

    name: str
    base_pose: Pose7
    feet: list[FootPlacement]
