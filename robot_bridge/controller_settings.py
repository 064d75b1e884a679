"""Settings of the simulated controller and the joint limits it enforces (no planner import: data only)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

#: Which plant the controller drives: ``kinematic`` replays the commanded positions; ``physics`` is the MuJoCo twin
#: (docs/physics.md).
PlantKind = Literal["kinematic", "physics"]


class ControllerSimSettings(BaseModel):
    """Playback and fault injection of the simulated controller."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    speed: float = Field(1.0, gt=0, le=1000, description="play trajectories this many times faster than real time "
                                                          "(physics plant: simulated time up to K x the wall clock)")
    plant: PlantKind = Field("kinematic", description="the plant the commands drive (docs/physics.md)")
    rate_hz: float = Field(200.0, gt=0, le=2000, description="control rate (wall clock; raised to "
                                                               "joint_states_per_motion_s x speed when that is more)")
    joint_states_per_motion_s: float = Field(
        60.0, gt=0, le=2000,
        description="measured joint states published per second of motion (at least, up to a 2 kHz control rate): "
                    "CONTRACT 7 asks for 50 at any speed, so a controller playing K times faster publishes 60 K a second",
    )
    start_buffer_s: float = Field(
        0.5, ge=0, le=10.0,
        description="wall-clock time of motion held before playback starts (plan time / speed), unless the whole job "
                    "is held first or the first segment has waited this long: at 10x a 0.25 s segment lasts 25 ms, and "
                    "a bridge paused longer than that by its host (a VM's steal) starved a controller that began at once",
    )
    progress_period_s: float = Field(0.05, gt=0, description="period of 'executing' progress reports")
    start_tolerance_rad: float = Field(0.02, gt=0, description="segment 0's first point vs the current posture")
    limit_tolerance_rel: float = Field(1e-6, ge=0, description="slack on the velocity limits")
    position_tolerance: float = Field(1e-9, ge=0, description="slack on the position limits (rad or m)")
    max_expiry_ahead_s: float = Field(
        10.0, gt=0, le=60.0,
        description="a command whose expires_at lies further than this (plus the clock skew) after its receipt is "
                    "refused: the contract's longest receipt deadline, so a leaked command cannot stay valid")
    drop_rate: float = Field(0.0, ge=0, le=1, description="share of incoming commands silently dropped")
    delay_ms: float = Field(0.0, ge=0, le=10_000, description="extra delay before a command is handled")
    crash_after: int | None = Field(None, ge=1, description="hard exit right after accepting this many segments")
    freeze_heartbeat_after_s: float | None = Field(
        None, ge=0, description="stop the heartbeat this long after the first accepted segment, staying alive otherwise"
    )
    seed: int = Field(0, description="seed of the drop decisions")
    controller_id: str = "controller-sim"
    stance: str = Field("upright", description="the stance the robot stands in, reported on state/joints")
    holding: Literal["none", "left", "right", "both"] = Field("none", description="what the hands hold at start")
    switch_interval_s: float = Field(
        0.0002, gt=0, le=0.005,
        description="Python's thread switch interval in the controller's process (run_controller sets it): a zenoh "
                    "callback waits at most about this long for the interpreter while the control or command thread "
                    "runs Python; at the default 5 ms, arriving commands waited up to 5 ms",
    )


@dataclass(frozen=True)
class JointLimits:
    """Position and velocity limits in the controller's own joint order."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray


def limits_from_urdf(path: str, joint_names: list[str]) -> JointLimits:
    """Position and velocity limits from the URDF, in ``joint_names`` order (the gate's parser, not the planner)."""
    from .urdf_kinematics import load_urdf

    model = load_urdf(path)
    order = {n: i for i, n in enumerate(model.joint_names)}
    missing = [n for n in joint_names if n not in order]
    if missing:
        raise ValueError(f"joints {missing} are not movable joints of {path}")
    idx = np.array([order[n] for n in joint_names])
    return JointLimits(lower=model.lower[idx], upper=model.upper[idx], velocity=model.velocity_limit[idx])


#: The fastest control loop the simulator runs, Hz (the settings' bound on ``rate_hz``).
MAX_CONTROL_RATE_HZ = 2000.0


def control_period(sim: ControllerSimSettings) -> tuple[float, int]:
    """The control loop's period (s, wall clock) and every how many ticks a joint state is published.

    Each tick plays ``period x speed`` seconds of motion whatever the machine's load, so publishing every
    ``every``-th tick gives ``1 / (period x speed x every)`` states per second of motion, never fewer than
    ``joint_states_per_motion_s`` while the loop need not run faster than ``MAX_CONTROL_RATE_HZ``."""
    wanted = sim.joint_states_per_motion_s * sim.speed
    rate = min(MAX_CONTROL_RATE_HZ, max(sim.rate_hz, wanted))
    return 1.0 / rate, max(1, int(rate // wanted))
