"""The twin's modelling settings, each with its stated default (docs/physics.md gives the reasons and the
sensitivity of the result to each).

A robot's spec may set servo gains, rotor inertia and contact in its ``sim:`` section (CONTRACT 1b); what it does
not set is derived from the model by the rules below.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class ServoDefaults(_Frozen):
    """How gains are derived where the spec's ``sim:`` section is silent."""

    stiffness_angle_rad: float = Field(0.05, gt=0, description="kp = effort limit / this: a joint deflected this far "
                                                               "from its command pushes back with its full torque")
    damping_ratio: float = Field(1.0, gt=0, description="kd = 2 x this x sqrt(kp x (joint inertia + armature)), the "
                                                        "joint inertia being the diagonal of the mass matrix at the "
                                                        "model's reference posture")
    armature_per_effort: float = Field(1e-3, ge=0, description="rotor inertia reflected through the gear, kg*m^2 per "
                                                               "N*m of effort limit (a harmonic-drive joint's order)")
    gravity_feedforward: bool = Field(True, description="add the static torques of the commanded posture (gravity on "
                                                        "robot and load, balanced by least-norm sole wrenches) to the "
                                                        "PD law")


class ContactSettings(_Frozen):
    """The soles against the floor (only the soles touch anything)."""

    timeconst_s: float = Field(0.005, gt=0.0019, le=0.1, description="MuJoCo solref time constant: contact softness")
    dampratio: float = Field(1.0, gt=0, le=10, description="MuJoCo solref damping ratio")
    impedance: tuple[float, float] = Field((0.99, 0.999), description="MuJoCo solimp dmin, dmax (width 1 mm): how "
                                                                       "much of the contact is rigid; MuJoCo's default "
                                                                       "(0.9, 0.95) let a loaded sole sink 5 mm")
    friction: float = Field(1.0, gt=0, le=5, description="sliding friction of sole on floor")


class StabilizerSettings(_Frozen):
    """CoP/DCM feedback through the ankles (ankle strategy) and the hips (hip strategy), at the control period."""

    enabled: bool = True
    dcm_gain: float = Field(2.0, ge=0, description="k in p_desired = p_ref + (1 + k/omega)(xi - xi_ref), 1/s")
    cop_gain: float = Field(4.0, ge=0, description="integral gain of the ankle moment on the CoP error, 1/s")
    cop_leak_s: float = Field(1.0, gt=0, description="time constant pulling the integrated ankle moment back to 0")
    hip_share: float = Field(0.3, ge=0, le=1, description="share of the corrective moment applied at the hips (the "
                                                          "rest at the ankles): the upper body leans against the error")
    polygon_inset_m: float = Field(0.01, ge=0, description="the desired ZMP is kept this far inside the polygon")


class FaultLimits(_Frozen):
    """When the twin's state is a fault (CONTRACT 9 kinds)."""

    fall_tilt_rad: float = Field(0.35, gt=0, description="base tilt beyond which the robot has fallen")
    fall_drop_m: float = Field(0.15, gt=0, description="pelvis drop below its settled height beyond which it fell")
    foot_tilt_rad: float = Field(0.05, gt=0, description="a supporting sole tilted beyond this rolls on its edge")
    foot_lift_m: float = Field(0.01, gt=0, description="a supporting sole's centre raised beyond this has lifted")
    saturation_s: float = Field(0.05, gt=0, description="a joint at its effort limit this long is saturated")
    payload_tolerance: float = Field(0.5, gt=0, description="the held load the wrists' force/torque sensors read may "
                                                            "differ from the planned object's weight by this share of "
                                                            "it (plus payload_floor_n) before it is a payload mismatch")
    payload_floor_n: float = Field(5.0, ge=0, description="added to the payload tolerance: sensor offset and the "
                                                          "motion's own accelerations on a light object")
    payload_settle_s: float = Field(0.1, ge=0, description="after a hand closes or opens the check waits the load ramp "
                                                           "plus this long (the weight coming onto the hand)")
    payload_debounce_s: float = Field(0.1, gt=0, description="a payload mismatch this long is a fault")


class TwinSettings(_Frozen):
    """Everything the twin's result depends on, apart from the robot and the plan."""

    timestep_s: float = Field(0.001, gt=0, le=0.005, description="physics step")
    settle_s: float = Field(1.0, ge=0, description="standing still in the first posture before the plan starts")
    load_ramp_s: float = Field(0.25, ge=0, description="the held object's weight comes onto the hand (and off it at "
                                                       "release) linearly over this time")
    mass_scale: float = Field(1.0, gt=0, le=100, description="scales the held object's mass only")
    servo: ServoDefaults = ServoDefaults()
    contact: ContactSettings = ContactSettings()
    stabilizer: StabilizerSettings = StabilizerSettings()
    faults: FaultLimits = FaultLimits()


class SimSection(_Frozen):
    """A robot spec's ``sim:`` section: per joint (or ``default``) kp, kd, armature; contact settings."""

    kp: dict[str, float] = Field(default_factory=dict)
    kd: dict[str, float] = Field(default_factory=dict)
    armature: dict[str, float] = Field(default_factory=dict)
    contact: dict[str, float] = Field(default_factory=dict)


def sim_section(spec: dict[str, Any]) -> SimSection:
    """The spec's ``sim:`` section, validated (empty when absent)."""
    return SimSection.model_validate(spec.get("sim") or {})
