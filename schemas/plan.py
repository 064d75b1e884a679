"""The plan file (``schema: regrasp.plan/1``, docs/contract.md section 3)."""

from __future__ import annotations

import hashlib
import json
from typing import Any, Literal

from pydantic import Field

from .common import HandConfig, Holding, OpenModel, Pose7, StrictModel
from .stance import StanceResult

PLAN_SCHEMA = "regrasp.plan/1"
FailureCode = Literal[
    "IK_FAIL", "NO_STABLE_GRASP", "COM_MARGIN", "COLLISION", "MOTION", "TIMEOUT", "CANCELED",
    "INVALID_REQUEST", "NO_PATH", "THRESHOLD_TOO_LARGE", "START_INVALID", "GOAL_INVALID",
]


class Failure(StrictModel):
    code: str
    message: str
    counts: dict[str, int] = Field(default_factory=dict)


class RobotRef(StrictModel):
    name: str
    urdf_sha256: str
    joint_names: list[str] | None = None


class ObjectRef(OpenModel):
    name: str
    mass_kg: float
    com_local: list[float]
    start_pose: Pose7
    goal_pose: Pose7


class TrajectoryPoint(StrictModel):
    t: float
    q: list[float]
    holding: Holding
    object_pose: list[float]
    com: list[float]
    margin_m: float
    zmp: list[float]
    effort_ratio: float | None = None


class Segment(StrictModel):
    kind: Literal["transit", "transfer", "handover", "approach", "retreat"]
    hand: Literal["left", "right", "both", "none"]
    first: int
    last: int


class Alternative(OpenModel):
    hands: str
    cost: float
    min_margin_m: float | None = None


class Plan(OpenModel):
    schema_: Literal["regrasp.plan/1"] = Field(PLAN_SCHEMA, alias="schema")
    status: Literal["solved", "infeasible"]
    failure: Failure | None = None
    robot: RobotRef
    scenario: dict[str, Any]
    stance: StanceResult
    support_polygon: list[list[float]]
    object: ObjectRef
    threshold_m: float
    hands: HandConfig | None = None
    dt_s: float = 0.005
    trajectory: list[TrajectoryPoint] = Field(default_factory=list)
    segments: list[Segment] = Field(default_factory=list)
    min_margin_m: float | None = None
    alternatives: list[Alternative] = Field(default_factory=list)
    stats: dict[str, Any] = Field(default_factory=dict)


def canonical_json(doc: Any) -> bytes:
    """The canonical bytes a plan's hash is taken over (docs/contract.md section 3)."""
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def plan_sha256(plan: dict[str, Any]) -> str:
    """SHA-256 of the plan's canonical JSON: what an approval binds to."""
    return hashlib.sha256(canonical_json(plan)).hexdigest()
