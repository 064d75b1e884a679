"""The robot spec: what a planner needs to know about a humanoid beyond its URDF.

Feet, soles, TCPs, arm and leg chains, waist, gripper and acceleration limits are
named here so that nothing downstream is specific to one model: the planner asks
the spec for "the left arm chain", never for ``LSC``.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Side = Literal["left", "right"]
SIDES: tuple[Side, Side] = ("left", "right")


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FootSpec(_Frozen):
    frame: str
    chain: list[str] = Field(min_length=6, max_length=6)


class GripperSpec(_Frozen):
    joint: str
    #: jaw opening (m) = opening_per_unit * (joint value - closed_value)
    opening_per_unit: float = 1.0
    max_opening_m: float
    closed_value: float = 0.0


class ArmSpec(_Frozen):
    chain: list[str]
    tcp: str
    gripper: GripperSpec


class UprightSpec(_Frozen):
    foot_y_m: float
    pelvis_height_m: float


class AccelerationLimits(_Frozen):
    legs: float
    waist: float
    neck: float
    arms: float
    grippers: float


class GripSpec(_Frozen):
    """A jaw hand's grip (per hand): friction coefficient, squeeze force per jaw (N), contact patch radius (m)."""

    friction: float = Field(gt=0)
    force_n: float = Field(gt=0)
    patch_radius_m: float = Field(gt=0)


class RobotSpec(_Frozen):
    name: str
    urdf: str
    description: str = ""
    root_link: str
    feet: dict[Side, FootSpec]
    arms: dict[Side, ArmSpec]
    waist: list[str]
    neck: list[str] = Field(default_factory=list)
    upright: UprightSpec
    default_posture_rad: dict[str, float] = Field(default_factory=dict)
    acceleration_limits: AccelerationLimits
    #: joint -> rad/s^2 (m/s^2 for prismatic joints), over the group limits (spec files give them per joint)
    acceleration_per_joint: dict[str, float] = Field(default_factory=dict)
    #: joint -> N*m (N for prismatic joints); overrides the URDF's <limit effort>
    effort_limits: dict[str, float] = Field(default_factory=dict)
    grip: GripSpec | None = None
    limit_sources: str = ""
    license_notice: str | None = None
    #: link pairs whose self-collision is never checked beyond the collision world's own rules (a spec
    #: file's ``srdf`` ``<disable_collisions>`` and its ``disable_collisions``), each pair sorted
    disabled_collisions: list[tuple[str, str]] = Field(default_factory=list)

    def acceleration_limit(self, joint: str) -> float:
        """Acceleration limit of a joint: its own, else the group it belongs to's."""
        if joint in self.acceleration_per_joint:
            return self.acceleration_per_joint[joint]
        acc = self.acceleration_limits
        if any(joint in f.chain for f in self.feet.values()):
            return acc.legs
        if joint in self.waist:
            return acc.waist
        if joint in self.neck:
            return acc.neck
        for arm in self.arms.values():
            if joint == arm.gripper.joint:
                return acc.grippers
            if joint in arm.chain:
                return acc.arms
        return min(acc.legs, acc.arms)

    def sole_frames(self) -> dict[Side, str]:
        return {side: foot.frame for side, foot in self.feet.items()}

    def tcp_frames(self) -> dict[Side, str]:
        return {side: arm.tcp for side, arm in self.arms.items()}
