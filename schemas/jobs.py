"""Wire models of the planning service's jobs (CONTRACT.md section 5).

These pydantic models are the single source of the HTTP API's wire format: the
FastAPI routes take and return them, so the OpenAPI document and the checks on
incoming requests both come from here.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import Field, Strict, StrictInt, StringConstraints

from .common import Finite, HandsChoice, OpenModel, StrictModel

JobKind = Literal["plan", "survey"]

JobState = Literal[
    "queued", "planning", "planned", "approved", "dispatching", "executing",
    "succeeded", "failed", "canceled", "rejected", "aborted",
]

#: States a job never leaves.
TERMINAL_STATES: frozenset[str] = frozenset({"succeeded", "failed", "canceled", "rejected", "aborted"})
#: States in which the planning work is still to be done or under way.
PLANNING_STATES: frozenset[str] = frozenset({"queued", "planning"})
#: States from which a cancel is accepted (the contract: "before dispatch").
CANCELABLE_STATES: frozenset[str] = frozenset({"queued", "planning", "planned", "approved"})
#: States in which the robot may be moving.
EXECUTION_STATES: frozenset[str] = frozenset({"dispatching", "executing"})

Role = Literal["planner", "approver", "operator", "admin"]
ROLES: tuple[str, ...] = ("planner", "approver", "operator", "admin")

#: Longest name accepted for a built-in scenario (names are short file stems).
MAX_NAME_LEN = 128
ScenarioName = Annotated[str, StringConstraints(min_length=1, max_length=MAX_NAME_LEN)]
#: A finite number that JSON true/false is not (pydantic's lax mode would read them as 1.0/0.0).
StrictFinite = Annotated[Finite, Strict()]


class JobRequest(StrictModel):
    """What to plan: a scenario plus the overrides of the ``regrasp plan`` command line."""

    scenario: ScenarioName | dict[str, Any] = Field(
        description="a built-in scenario name, or an inline scenario document (CONTRACT.md section 2)",
    )
    stance: ScenarioName | None = Field(None, description="built-in stance name overriding the scenario's")
    threshold_m: StrictFinite | None = Field(None, ge=0, le=0.5, description="CoM margin threshold, m; 0 = unconstrained planner")
    hands: HandsChoice | None = Field(None, description="hand configuration overriding the scenario's")
    # Strict: JSON true/false are not numbers here (pydantic's lax mode would read them as 1/0).
    seed: StrictInt | None = Field(None, ge=0, le=2**63 - 1, description="random seed; the same seed gives the same plan")
    states_per_configuration: StrictInt | None = Field(None, ge=1, le=1_000_000,
                                                       description="survey: states evaluated per hand configuration")
    time_limit_s: StrictFinite | None = Field(None, gt=0, le=3600, description="planner safety-net time limit, s")



class JobSubmit(StrictModel):
    """Body of ``POST /v1/jobs``."""

    kind: JobKind
    request: JobRequest


class JobErrorInfo(OpenModel):
    """Why a job ended without success: a failure code (the planner's or the service's) and a message."""

    code: str
    message: str


class Approval(StrictModel):
    """An approval: who, when, until when, and the plan hash it binds to."""

    approved_by: str
    approved_at: datetime
    expires_at: datetime
    plan_sha256: str
    comment: str | None = None


class Provenance(StrictModel):
    """What a job ran with, so its result can be reproduced."""

    seed: int | None = None
    code_version: str | None = None
    robot: str | None = None
    robot_sha256: str | None = None
    library_versions: dict[str, str] = Field(default_factory=dict)


class Job(StrictModel):
    """A job as the API returns it."""

    id: str
    kind: JobKind
    state: JobState
    progress: float = Field(ge=0, le=1, description="fraction of the planning work done")
    message: str | None = Field(None, description="last progress or state message")
    submitter: str
    request: dict[str, Any]
    result: dict[str, Any] | None = Field(None, description="plan (section 3) or survey (section 4) document")
    error: JobErrorInfo | None = None
    plan_sha256: str | None = None
    approval: Approval | None = None
    cancel_requested: bool = False
    attempts: int = 0
    provenance: Provenance
    audit_head: str | None = Field(None, description="SHA-256 chain head of the job's audit file")
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None


class JobList(StrictModel):
    jobs: list[Job]
    total: int = Field(description="number of jobs matching the filters")
    limit: int
    offset: int


class ApproveBody(StrictModel):
    """Body of ``POST /v1/jobs/{id}/approve`` (optional)."""

    plan_sha256: str | None = Field(
        None, pattern=r"^[0-9a-f]{64}$",
        description="the plan hash the approver reviewed; refused if it is not the job's current plan",
    )
    comment: str | None = Field(None, max_length=2000)


class ReasonBody(StrictModel):
    """Body of reject, cancel and stop (optional)."""

    reason: str | None = Field(None, max_length=2000)


class JobEvent(StrictModel):
    """One entry of a job's event stream (SSE ``data``)."""

    id: int
    job_id: str
    at: datetime
    kind: str = Field(description="state | progress | approval | bridge | note")
    state: JobState | None = None
    progress: float | None = None
    message: str | None = None
    data: dict[str, Any] = Field(default_factory=dict)


class Health(StrictModel):
    status: Literal["ok", "degraded"]
    database: str
    executor: str
    workers: int
    queue_depth: int
    controller_alive: bool
    version: str


class Problem(OpenModel):
    """RFC 9457 problem details."""

    type: str = "about:blank"
    title: str
    status: int
    detail: str
    instance: str | None = None
