"""The safety gate's inputs and its veto: settings, the approval, the measured state, the robot it loads.

Part of the gate (:mod:`robot_bridge.gate`), which never imports the planner or pinocchio.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Sequence

from pydantic import BaseModel, ConfigDict, Field

from .errors import BridgeError
from .robot_files import RobotFiles
from .urdf_kinematics import UrdfModel

_HOLDING = ("none", "left", "right", "both")


class GateSettings(BaseModel):
    """Tolerances and sampling of the gate; defaults follow the plan format (schemas.plan)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    controller_period_s: float = Field(0.005, gt=0, description="the controller's interpolation period (200 Hz)")
    oversample: int = Field(2, ge=1, le=16, description="samples per controller period (2: the midpoints too)")
    margin_tolerance_m: float = Field(1e-4, ge=0, description="the contract's tolerance on the CoM margin")
    zmp_tolerance_m: float = Field(1e-4, ge=0, description="how far outside the polygon a ZMP may be (rounding)")
    start_tolerance_rad: float = Field(0.01, gt=0, description="first point vs the measured state, per joint")
    feet_tolerance_m: float = Field(1e-3, gt=0, description="soles vs the stance's foot placements")
    position_tolerance: float = Field(1e-9, ge=0, description="slack on the URDF position limits (rad or m)")
    limit_tolerance_rel: float = Field(1e-6, ge=0, description="relative slack on velocity/acceleration limits")
    time_tolerance_s: float = Field(1e-6, ge=0, description="|t_i - i dt_s| allowed")
    gravity: float = Field(9.81, gt=0)
    check_limits: bool = Field(True, description="check static joint torques and grip against the robot's limits")
    max_points: int = Field(720_000, gt=0, description="largest trajectory accepted (1 h at 200 Hz)")


@dataclass(frozen=True)
class Approval:
    """What an approver signed: the plan's SHA-256, valid until ``expires_at``."""

    sha256: str
    expires_at: datetime


@dataclass(frozen=True)
class MeasuredState:
    """The robot's measured joint positions, by name (from ``state/joints``)."""

    joint_names: Sequence[str]
    q: Sequence[float]
    tolerance_rad: float | None = None


class Veto(BridgeError):
    """Raised inside the gate to stop at the first failing check."""

    def __init__(self, check: str, message: str, sample_index: int | None = None):
        super().__init__(message)
        self.check = check
        self.message = message
        self.sample_index = sample_index


@dataclass(frozen=True)
class _Robot:
    files: RobotFiles
    model: UrdfModel
    urdf_sha256: str
