"""Messages of the robot bridge (docs/contract.md section 6) and the safety gate's verdict.

Commands (bridge -> controller) are strict: a controller must refuse a segment
with a field it does not understand rather than guess. Telemetry (controller ->
bridge) tolerates extra fields, so a newer controller can add diagnostics
without breaking older bridges.

Key expressions, ``ROBOT`` being the robot id (default ``hrp5p``):

- ``regrasp/ROBOT/cmd/trajectory``: :class:`TrajectorySegment`
- ``regrasp/ROBOT/cmd/stop``: :class:`Stop`
- ``regrasp/ROBOT/cmd/heartbeat``: :class:`CommandHeartbeat` (the dispatcher's, during an execution)
- ``regrasp/ROBOT/state/joints``: :class:`JointState`
- ``regrasp/ROBOT/state/exec``: :class:`ExecStatus`
- ``regrasp/ROBOT/state/heartbeat``: :class:`Heartbeat`
- liveliness token ``regrasp/ROBOT/alive/controller`` while a controller is up.

Every command carries ``expires_at`` (Unix time, s: the latest receipt the
controller accepts) and ``sig``, an Ed25519 signature over the message without
``sig`` in canonical JSON (``robot_bridge.signing``).
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from .common import Holding, OpenModel, StrictModel

#: The contract's upper bound on the duration of one segment's points.
MAX_SEGMENT_DURATION_S = 1.0

ExecStatusValue = Literal[
    "accepted",  # a segment was buffered
    "duplicate",  # a re-sent copy of a segment already held: dropped, harmless
    "refused",  # a command that does not fit: signature, expiry, job or sequence (the controller did not move for it)
    "rejected",  # a segment was refused by the controller's own checks (limits, start mismatch, joint names)
    "executing",  # progress while playing
    "succeeded",  # the last point of the last segment was reached
    "stopped",  # a stop was honoured; the controller holds its posture
    "starved",  # the next point was not there in time; the controller holds the last command
    "fault",  # the controller's own checks stopped execution
]


class TrajectorySegment(StrictModel):
    """At most 1 s of points; the controller plays them at ``dt_s`` from the start of segment 0."""

    job_id: str = Field(min_length=1, max_length=200)
    plan_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    seq: int = Field(ge=0, description="strictly increasing per job; the controller drops stale ones")
    segment_index: int = Field(ge=0)
    segment_count: int = Field(ge=1)
    joint_names: list[str] = Field(min_length=1)
    dt_s: float = Field(gt=0, le=MAX_SEGMENT_DURATION_S)
    t_from_start: float = Field(ge=0, description="time of the first point from the start of segment 0 (s)")
    points: list[list[float]] = Field(min_length=1)
    holding: list[Holding] = Field(min_length=1)
    first_index: int | None = Field(None, ge=0, description="index of the first point in the plan's trajectory")
    object_mass_kg: float | None = Field(None, ge=0, le=1000, allow_inf_nan=False,
                                         description="the plan's object mass (kg): what the hands are planned to hold, "
                                                     "for the controller's payload check (optional)")
    expires_at: float | None = Field(None, description="Unix time (s): the latest receipt the controller accepts")
    sig: str | None = Field(None, description="Ed25519 signature (base64) over the canonical JSON without sig")

    @model_validator(mode="after")
    def _check(self) -> "TrajectorySegment":
        if self.segment_index >= self.segment_count:
            raise ValueError(f"segment_index {self.segment_index} is not below segment_count {self.segment_count}")
        if len(self.holding) != len(self.points):
            raise ValueError(f"holding has {len(self.holding)} entries for {len(self.points)} points")
        n = len(self.joint_names)
        if len(set(self.joint_names)) != n:
            raise ValueError("joint_names lists a joint twice")
        for i, p in enumerate(self.points):
            if len(p) != n:
                raise ValueError(f"points[{i}] has {len(p)} values for {n} joint_names")
        flat = [v for p in self.points for v in p]
        if not all(map(math.isfinite, flat)):
            k = next(k for k, v in enumerate(flat) if not math.isfinite(v))
            raise ValueError(f"points[{k // n}][{k % n}] ({self.joint_names[k % n]}) is {flat[k]!r}; values must be finite")
        if not math.isfinite(self.t_from_start) or not math.isfinite(self.dt_s):
            raise ValueError("t_from_start and dt_s must be finite")
        if (len(self.points) - 1) * self.dt_s > MAX_SEGMENT_DURATION_S + 1e-9:
            raise ValueError(f"a segment holds at most {MAX_SEGMENT_DURATION_S} s of points, got {(len(self.points) - 1) * self.dt_s:.3f} s")
        return self


class Stop(StrictModel):
    """Stop now: a controlled stop, balance kept. ``job_id`` None stops whatever runs."""

    job_id: str | None = None
    reason: str = ""
    stamp: float | None = Field(None, description="sender's monotonic clock (s), for latency measurements")
    expires_at: float | None = Field(None, description="Unix time (s); a stop is obeyed whatever it says")
    sig: str | None = Field(None, description="signature; a stop is obeyed unsigned too, and logged as such")


class CommandHeartbeat(StrictModel):
    """The dispatcher's heartbeat on ``cmd/heartbeat`` while it runs an execution: the controller's dead-man.

    ``seq`` is its own counter (strictly increasing per job), apart from the segments' ``seq``."""

    job_id: str = Field(min_length=1, max_length=200)
    seq: int = Field(ge=0)
    t: float = Field(description="sender's Unix time (s)")
    expires_at: float = Field(description="Unix time (s): the latest receipt the controller accepts")
    sig: str | None = None


class JointState(OpenModel):
    """Measured joint positions, published by the controller at its control rate (200 Hz)."""

    stamp: float = Field(description="controller's monotonic clock (s)")
    joint_names: list[str]
    q: list[float]
    job_id: str | None = None
    index: int | None = Field(None, description="trajectory index being played, if executing")
    stance: str | None = Field(None, description="the stance the robot stands in (its feet), for a recover job")
    holding: Holding | None = Field(None, description="what the hands hold now")

    @field_validator("q")
    @classmethod
    def _finite(cls, q: list[float]) -> list[float]:
        for i, v in enumerate(q):
            if not math.isfinite(v):
                raise ValueError(f"q[{i}] is {v!r}")
        return q


#: The words of a controller's refusal of a segment of a job it has itself ended (stopped, faulted, finished):
#: ``job <id> was ended by this controller (<how>); ...``. The bridge, told so, waits briefly for the controller's own
#: report of that end (its heartbeat while it holds) and records that as the job's end.
ENDED_BY_CONTROLLER = "was ended by this controller"


class ExecStatus(OpenModel):
    """Execution progress and every accept/reject decision of the controller."""

    job_id: str | None
    seq: int | None
    index: int | None = Field(None, description="trajectory index reached")
    status: ExecStatusValue
    reason: str = ""
    received_at: float | None = Field(None, description="controller's monotonic clock when the command arrived (s)")
    fatal: bool = Field(True, description="for 'rejected' and 'refused': False when the job goes on (a segment ahead "
                                          "of a gap, not buffered; the bridge sends the missing one again)")
    kind: str | None = Field(None, description="the command the status answers: trajectory, stop or heartbeat")


class Heartbeat(OpenModel):
    """The application heartbeat the bridge's watchdog follows (a frozen controller keeps its token)."""

    controller_id: str
    count: int = Field(ge=0)
    stamp: float
    state: Literal["idle", "executing", "holding"] = "idle"
    job_id: str | None = None
    status: ExecStatusValue | None = Field(None, description="while holding: how the controller ended job_id "
                                                             "(stopped, fault, ...), as it reported on state/exec")
    reason: str = Field("", description="while holding: the controller's reason for that end")


# --------------------------------------------------------------------------- gate verdict

GateCheck = Literal[
    "approval",  # an approval exists and has not expired
    "plan_hash",  # the plan's SHA-256 equals the approved one
    "structure",  # a solved plan of the right schema, robot, joint names and sizes
    "robot_model",  # the plan was made for the URDF the gate loads
    "finite",  # no NaN or Inf
    "time",  # time strictly increasing at dt_s
    "start_state",  # first point matches the measured robot state
    "joint_position",
    "joint_velocity",
    "joint_acceleration",
    "feet",  # the soles stay where the stance puts them
    "com_margin",  # CoM margin with the held object >= threshold - tolerance at every sample
    "zmp",  # cart-table ZMP inside the support polygon
    "effort",  # static joint torques (robot, held object, contact wrenches) within the effort limits
    "grip",  # the jaws' friction holds the held object's weight and its moment about the closing axis
    "policy",  # the site's safety policy (schemas.policy): threshold floor, object mass, speed, physics dry run
    "gate_error",  # the gate itself failed: fail closed
]


class GateVerdict(StrictModel):
    """The safety gate's decision. A veto names the check and the first failing sample."""

    passed: bool
    check: GateCheck | None = Field(None, description="the failing check (None when passed)")
    sample_index: int | None = Field(None, description="first failing sample on the gate's grid")
    point_index: int | None = Field(None, description="plan trajectory point at or before that sample")
    t: float | None = Field(None, description="time of the failing sample from the plan start (s)")
    message: str
    plan_sha256: str | None = None
    threshold_m: float | None = Field(None, description="the margin every sample was checked against: the larger of "
                                                         "the plan's threshold and the policy's floor")
    policy_sha256: str | None = Field(None, description="SHA-256 of the safety policy that judged the plan")
    samples: int = Field(0, description="samples checked on the gate's grid")
    elapsed_s: float = 0.0
    checks_passed: list[str] = Field(default_factory=list)
    skipped: list[str] = Field(default_factory=list, description="checks not run (offline mode)")
    stats: dict[str, dict[str, Any]] = Field(default_factory=dict, description="per-check figures")

    def summary(self) -> str:
        if self.passed:
            return f"gate passed: {self.samples} samples, {len(self.checks_passed)} checks ({self.message})"
        where = ""
        if self.sample_index is not None:
            where = f" at sample {self.sample_index} (point {self.point_index}, t = {self.t:.3f} s)"
        return f"gate veto [{self.check}]{where}: {self.message}"
