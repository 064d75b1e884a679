"""The rules every IK descent of the project follows, in one place: its settings, its stopping
rules, and which joints it moves. The pinocchio descent (:mod:`planner.motion.ik`) and the
compiled batch descent (:mod:`planner.motion.ik_batch`) both read them from here.
"""

from __future__ import annotations

from typing import Literal, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.robot.model import RobotModel

Side = Literal["left", "right"]
#: An attempt stops when its error has not improved by 2 % for this many iterations.
STALL_ITERATIONS = 8
STALL_IMPROVEMENT = 0.02
#: Re-solves per iteration with the joints pinned at a limit removed.
LIMIT_PASSES = 3
LIMIT_EPS = 1e-9


class IkSettings(BaseModel):
    """Tolerances and effort of one IK solve."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    pos_tol_m: float = Field(1e-3, gt=0, description="TCP position tolerance")
    rot_tol_rad: float = Field(1e-2, gt=0, description="TCP orientation tolerance")
    max_iterations: int = Field(50, ge=1, description="DLS iterations per attempt")
    restarts: int = Field(6, ge=0, description="random restarts after the seeded attempt")
    damping: float = Field(1e-2, gt=0, description="DLS damping lambda (m or rad)")
    max_step_rad: float = Field(0.6, gt=0, description="largest joint change per iteration")
    nullspace_gain: float = Field(0.05, ge=0, description="pull towards the rest posture, per iteration")
    use_waist: bool = Field(True, description="let the waist joints help the arm(s)")
    #: A target farther than reach * this from the shoulder is rejected without iterating.
    reach_slack: float = Field(1.05, gt=0)
    restart_noise_rad: float = Field(0.6, gt=0, description="std of the restart perturbation around the seed")
    restart_max_residual_m: float = Field(
        1.0, gt=0, description="restart only while the best position residual is below this (farther targets are out of reach)"
    )



def active_columns(robot: RobotModel, settings: IkSettings, sides: Sequence[Side]) -> np.ndarray:
    """Wire columns IK moves for these hands: waist (if ``settings`` use it) then each arm."""
    parts = [robot.waist_indices()] if settings.use_waist else []
    parts += [robot.arm_indices(s) for s in sides]
    return np.concatenate(parts).astype(int)
