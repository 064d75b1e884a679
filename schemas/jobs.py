"""Wire models of the planning service's jobs (docs/contract.md section 5).

These pydantic models are the single source of the HTTP API's wire format: the
FastAPI routes take and return them, so the OpenAPI document and the checks on
incoming requests both come from here.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import (
    BeforeValidator,
    ConfigDict,
    Field,
    StringConstraints,
    ValidationInfo,
    field_validator,
    model_validator,
)

from .common import Finite, HandsChoice, OpenModel, StrictModel

JobKind = Literal["plan", "survey", "recover"]

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
#: A built-in scenario name (kept for importers; requests take :data:`ScenarioRef`).
ScenarioName = Annotated[str, StringConstraints(min_length=1, max_length=MAX_NAME_LEN)]
#: Bounds of an inline scenario document: values in all (every list item and mapping entry counted) and nesting.
MAX_DOCUMENT_VALUES = 5_000
MAX_DOCUMENT_DEPTH = 12


def _bounded_document(doc: Any) -> Any:
    """Refuse a document with more than MAX_DOCUMENT_VALUES values or nested deeper than MAX_DOCUMENT_DEPTH.

    Runs before any other validation, so an oversized list is refused after counting at most
    MAX_DOCUMENT_VALUES values (not after validating every item of it).
    """
    if not isinstance(doc, dict):
        return doc
    stack: list[tuple[Any, int]] = [(doc, 1)]
    seen = 0
    while stack:
        value, depth = stack.pop()
        if depth > MAX_DOCUMENT_DEPTH:
            raise ValueError(f"the document is nested deeper than {MAX_DOCUMENT_DEPTH} levels")
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else ()
        for child in children:
            seen += 1
            if seen > MAX_DOCUMENT_VALUES:
                raise ValueError(f"the document holds more than {MAX_DOCUMENT_VALUES} values; a scenario is far smaller")
            if isinstance(child, (dict, list)):
                stack.append((child, depth + 1))
    return doc


def _scenario_value(value: Any) -> Any:
    """A scenario is a name or a document; anything else is refused with one clear message."""
    if isinstance(value, str):
        if not 1 <= len(value) <= MAX_NAME_LEN:
            raise ValueError(f"a scenario name has 1 to {MAX_NAME_LEN} characters")
        return value
    if isinstance(value, dict):
        return _bounded_document(value)
    raise ValueError("a scenario is a registered scenario name or an inline scenario document (a JSON object)")


ScenarioRef = Annotated[str | dict[str, Any], BeforeValidator(_scenario_value)]
#: A registered name of a stance or robot (the service checks it is registered, and says which are).
RegisteredName = Annotated[str, StringConstraints(min_length=1, max_length=MAX_NAME_LEN)]


class JobRequest(StrictModel):
    """What to plan: a scenario plus the overrides of the ``regrasp plan`` command line.

    Types are strict (``"seed": "1"`` or ``true`` is an error, not a coercion): a client that
    sends the wrong type has a bug worth hearing about.
    """

    model_config = ConfigDict(extra="forbid", populate_by_name=True, strict=True)

    scenario: ScenarioRef = Field(
        description="a registered scenario name, or an inline scenario document (docs/contract.md section 2) "
                    "whose robot, stance and mesh are registered names",
    )
    stance: RegisteredName | None = Field(None, description="registered stance name overriding the scenario's")
    robot: RegisteredName | None = Field(None, description="registered robot name overriding the scenario's")
    threshold_m: Finite | None = Field(None, ge=0, le=0.5, description="CoM margin threshold, m; 0 = unconstrained planner")
    hands: HandsChoice | None = Field(None, description="hand configuration overriding the scenario's")
    seed: int | None = Field(None, ge=0, le=2**63 - 1, description="random seed; the same seed gives the same plan")
    states_per_configuration: int | None = Field(None, ge=1, le=1_000_000,
                                                 description="survey (regrasp.survey/1 form): read as until: states with this many states per seed")
    until: Literal["solved", "states"] | None = Field(None, description="survey estimator (also for a plan's hands: auto): "
                                                      "seeds until the intervals are tight, or a fixed number of states per seed")
    ci_half_width: Finite | None = Field(None, gt=0, le=0.5, description="survey: largest distance of the 95 % bounds from R")
    seeds_min: int | None = Field(None, ge=1, le=10_000, description="survey: fewest seeds per configuration")
    seeds_max: int | None = Field(None, ge=1, le=10_000, description="survey: most seeds per configuration")
    states_per_seed: int | None = Field(None, ge=1, le=1_000_000, description="survey, until: states: states counted per seed")
    time_limit_s: Finite | None = Field(None, gt=0, le=3600, description="planner safety-net time limit, s")
    speed_scale: Finite | None = Field(None, gt=0, le=1, description="plan: share of the time-optimal speed the "
                                       "motion is timed at (0 < S <= 1), overriding the scenario's")



class RecoverRequest(StrictModel):
    """A recover job: plan from the controller's measured joint state back to its stance posture."""

    robot: Annotated[str, StringConstraints(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_\-]+$")] = Field(
        description="the robot id whose controller reports the state (the bridge's ROBOT)")
    threshold_m: Finite | None = Field(None, ge=0, le=0.5, description="CoM margin kept where it can be, m")
    seed: int | None = Field(None, ge=0, le=2**63 - 1, description="seed of the path search")


class JobSubmit(StrictModel):
    """Body of ``POST /v1/jobs``."""

    kind: JobKind
    request: JobRequest | RecoverRequest

    @field_validator("request", mode="before")
    @classmethod
    def _request_of_kind(cls, value: Any, info: ValidationInfo) -> Any:
        """Validate the request as the kind's own model, so an error names its field (``request.scenario``)."""
        if isinstance(value, (JobRequest, RecoverRequest)):
            return value
        return (RecoverRequest if info.data.get("kind") == "recover" else JobRequest).model_validate(value)

    @model_validator(mode="after")
    def _request_fits_kind(self) -> "JobSubmit":
        if (self.kind == "recover") != isinstance(self.request, RecoverRequest):
            want = "{robot}" if self.kind == "recover" else "{scenario, ...}"
            raise ValueError(f"a {self.kind} job takes a request of the form {want}")
        return self


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
    comparison: bool = Field(False, description="a plan made below the site's safety floor (CONTRACT 5): shown beside "
                                                "the task's plan, never approvable or dispatchable")
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


class RejectBody(StrictModel):
    """Body of ``POST /v1/jobs/{id}/reject``: why the plan is declined (required; stored and audited)."""

    reason: str = Field(min_length=1, max_length=2000, pattern=r"\S",
                        description="why the plan is declined, in words (kept with the job and in its audit file)")


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
    robot_id: str | None = Field(None, description="the robot this service's bridge drives (what a recover job names)")
    balance_age_s: float | None = Field(
        None, description="seconds since the controller's last balance sample (a physics plant's state/balance) "
                          "reached the service; None when none has (a kinematic controller publishes none)")


class Problem(OpenModel):
    """RFC 9457 problem details."""

    type: str = "about:blank"
    title: str
    status: int
    detail: str
    instance: str | None = None
