"""The robot spec: what a planner needs to know about a humanoid beyond its URDF.

Feet, soles, TCPs, arm and leg chains, waist, gripper and acceleration limits are
named here so that nothing downstream is specific to one model: the planner asks
the spec for "the left arm chain", never for ``LSC``.

A :class:`RobotSpec` is never read from a file as it is: it is what
:func:`planner.robot.spec_file.derive` makes of a robot spec file (``regrasp.robot/1``)
and its URDF, with the chains found in the URDF's tree and every limit per joint.
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
    #: the jaw; None for a rigid hand, which holds by attaching the object at its TCP
    gripper: GripperSpec | None = None


class UprightSpec(_Frozen):
    foot_y_m: float
    pelvis_height_m: float


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
    #: movable joints beyond an arm's end that are neither its chain nor its jaw (fingers of a rigid hand)
    hand_joints: list[str] = Field(default_factory=list)
    upright: UprightSpec
    default_posture_rad: dict[str, float] = Field(default_factory=dict)
    #: joint -> rad/s^2 (m/s^2 for prismatic joints), every movable non-mimic joint of the URDF
    acceleration_limits: dict[str, float]
    #: joint -> N*m (N for prismatic joints); overrides the URDF's <limit effort>
    effort_limits: dict[str, float] = Field(default_factory=dict)
    grip: GripSpec | None = None
    limit_sources: str = ""
    license_notice: str | None = None
    #: link pairs whose self-collision is never checked beyond the collision world's own rules (a spec
    #: file's ``srdf`` ``<disable_collisions>`` and its ``disable_collisions``), each pair sorted
    disabled_collisions: list[tuple[str, str]] = Field(default_factory=list)
    #: where the self-collision matrix comes from: the robot's SRDF, or computed over random configurations
    #: (:mod:`planner.scene.collision_matrix`, cached by URDF and spec)
    self_collision_matrix: Literal["computed", "srdf"] = "computed"

    def acceleration_limit(self, joint: str) -> float:
        """Acceleration limit of a joint (rad/s^2, m/s^2 for a prismatic joint)."""
        try:
            return self.acceleration_limits[joint]
        except KeyError:
            raise KeyError(f"robot {self.name!r} has no acceleration limit for joint {joint!r}") from None

    def sole_frames(self) -> dict[Side, str]:
        return {side: foot.frame for side, foot in self.feet.items()}

    def tcp_frames(self) -> dict[Side, str]:
        return {side: arm.tcp for side, arm in self.arms.items()}
