"""``/v1/jobs``: submit, read, list, stream, cancel, approve, reject, dispatch, stop, audit (docs/contract.md section 5)."""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import time
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, AsyncIterator, Iterator

from fastapi import APIRouter, Body, Depends, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from planner.api.catalogue import RequestNameError, check_request
from schemas.jobs import (
    CANCELABLE_STATES,
    EXECUTION_STATES,
    TERMINAL_STATES,
    ApproveBody,
    Job,
    JobKind,
    JobList,
    JobState,
    JobSubmit,
    ReasonBody,
    RejectBody,
)
from schemas.scenario import Scenario

from ..context import Service
from ..execution.dispatch import RobotBusy
from ..execution.physics_gate import dispatch_physics
from ..jobs.provenance import provenance
from ..store.repo import Conflict, IdempotencyMismatch, QueueFull, UserQueueFull
from .auth import Principal
from .deps import principal, problems, require, service
from .problems import PROBLEM_TYPE_BASE, ProblemError, clean_message
from .views import job_view

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
#: Events read from the store per query of an SSE stream.
EVENT_PAGE = 500


def _load(svc: Service, job_id: str) -> dict[str, Any]:
    if len(job_id) > 64:
        raise ProblemError(404, f"no job {job_id[:64]!r}...")
    row = svc.store.get(job_id)
    if row is None:
        raise ProblemError(404, f"no job with id {job_id!r}")
    if row["state"] == "approved" and row["approval_expires_at"] is not None \
            and row["approval_expires_at"] < datetime.now(timezone.utc):
        svc.store.expire_approvals(job_id)
        row = svc.store.get(job_id) or row
    return row


def _job_json(svc: Service, row: dict[str, Any]) -> str:
    """The job as JSON with its stored result spliced in verbatim: a plan of several MB is never re-parsed."""
    text = svc.store.result_text(row["id"]) if row["state"] not in ("queued", "planning") else None
    body = job_view(row).model_dump_json(exclude={"result"})
    return body[:-1] + ',"result":' + (text if text is not None else "null") + "}"


def _job_response(svc: Service, row: dict[str, Any], status_code: int = 200,
                  headers: dict[str, str] | None = None) -> Response:
    return Response(_job_json(svc, row), status_code=status_code, media_type="application/json", headers=headers)


# ------------------------------------------------------------------ submit
def _name_problem(exc: RequestNameError) -> ProblemError:
    return ProblemError(422, str(exc), type_=PROBLEM_TYPE_BASE + "unknown-name", field=exc.field, valid=exc.valid)


def _check_request(svc: Service, body: JobSubmit) -> tuple[str, int | None]:
    """Validate what pydantic cannot (registered names, inline scenarios, the service's caps); returns (robot, seed).

    A request names things and never a file: every name is checked against the registered
    ones here (422 listing the valid names), and again by the worker before it loads anything.
    """
    req = body.request
    robot, seed = req.robot or "hrp5p", req.seed
    try:
        check_request(req.model_dump(mode="json", exclude_none=True),
                      require_registered_scenario=svc.settings.check_scenario_names)
    except RequestNameError as exc:
        raise _name_problem(exc) from None
    scenario: Scenario | None = None
    if isinstance(req.scenario, dict):
        from pydantic import ValidationError

        try:
            scenario = Scenario.model_validate(req.scenario)
        except ValidationError as exc:
            lines = [f"request.scenario.{'.'.join(str(p) for p in e['loc'])}: {clean_message(e['msg'])}"
                     for e in exc.errors()[:10]]
            more = exc.error_count() - len(lines)
            raise ProblemError(422, "the inline scenario is invalid: " + "; ".join(lines)
                               + (f" (and {more} more)" if more > 0 else "")) from None
        robot = req.robot or scenario.robot
        seed = seed if seed is not None else scenario.seed
    _check_caps(svc, body, scenario)
    return robot, seed


def _check_caps(svc: Service, body: JobSubmit, scenario: Scenario | None) -> None:
    """The service's bounds on one job's work: states per hand configuration and planning time."""
    req, cfg = body.request, svc.settings
    states = req.states_per_configuration
    per_seed = getattr(req, "states_per_seed", None)
    if states is None and scenario is not None:
        states = getattr(scenario.survey, "states_per_configuration", None)
    for label, value in (("states_per_configuration", states), ("states_per_seed", per_seed)):
        if value is not None and value > cfg.max_states_per_configuration:
            raise ProblemError(422, f"request.{label} is {value}: this service runs at most "
                                    f"{cfg.max_states_per_configuration} states per hand configuration per job; "
                                    "ask for fewer states", type_=PROBLEM_TYPE_BASE + "over-limit")
    time_s = req.time_limit_s if req.time_limit_s is not None else (scenario.limits.time_s if scenario else None)
    if time_s is not None and time_s > cfg.job_timeout_s:
        raise ProblemError(422, f"a time limit of {time_s:g} s is over this service's limit of {cfg.job_timeout_s:g} s "
                                "per job", type_=PROBLEM_TYPE_BASE + "over-limit")


@router.post(
    "", status_code=202, response_model=Job,
    summary="Submit a plan or survey job",
    responses={**problems(400, 401, 403, 409, 413, 422, 429, 503),
               202: {"description": "Accepted (also for a replay of the same Idempotency-Key)",
                     "headers": {"Location": {"description": "URL of the job", "schema": {"type": "string"}}}}},
)
def submit(
    body: JobSubmit,
    idempotency_key: str | None = Header(None, alias="Idempotency-Key", max_length=255, min_length=1,
                                         description="same key + same body = same job (per submitter)"),
    p: Principal = Depends(principal),
    svc: Service = Depends(service),
) -> Response:
    sick = svc.storage.check() if svc.storage is not None else None
    if sick is not None:
        raise ProblemError(503, f"the service cannot take jobs now: {sick}", title="Storage unavailable",
                           headers={"Retry-After": str(svc.settings.retry_after_s)})
    if body.kind == "recover":
        require("operator", p, "submitting a recover job")
        robot, seed = svc.settings.robot, body.request.seed
        request = _recover_request(svc, body)
    else:
        require("planner", p, "submitting a job")
        robot, seed = _check_request(svc, body)
        request = body.request.model_dump(mode="json", exclude_none=True)
    # What the submitter sent (a recover job's stored request adds the measured state, which a replay would not match).
    asked = body.request.model_dump(mode="json", exclude_none=True)
    request_sha = hashlib.sha256(json.dumps({"kind": body.kind, "request": asked}, sort_keys=True).encode()).hexdigest()
    try:
        row, created = svc.store.create(
            job_id=str(uuid.uuid4()), kind=body.kind, submitter=p.user, request=request, request_sha256=request_sha,
            idempotency_key=idempotency_key, provenance=provenance(robot, seed), queue_limit=svc.settings.queue_limit,
            user_limit=svc.settings.user_queue_limit,
        )
    except IdempotencyMismatch as exc:
        raise ProblemError(409, str(exc)) from None
    except QueueFull as exc:
        raise ProblemError(429, f"the queue holds {exc.depth} jobs, at its limit of {svc.settings.queue_limit}; "
                                f"retry in {svc.settings.retry_after_s} s",
                           headers={"Retry-After": str(svc.settings.retry_after_s)}) from None
    except UserQueueFull as exc:
        raise ProblemError(429, f"user {p.user!r} has {exc.count} jobs queued or planning, at the limit of "
                                f"{svc.settings.user_queue_limit} per user; retry when some have finished",
                           headers={"Retry-After": str(svc.settings.retry_after_s)}) from None
    headers = {"Location": f"/v1/jobs/{row['id']}"}
    if not created:
        headers["Idempotent-Replayed"] = "true"
    return _job_response(svc, row, 202, headers)


def _recover_request(svc: Service, body: JobSubmit) -> dict[str, Any]:
    """A recover job's stored request: what was asked, and the controller's measured state it plans from."""
    req = body.request
    robot_id = getattr(svc.bridge, "robot_id", None)
    if robot_id is not None and req.robot != robot_id:
        raise ProblemError(422, f"unknown robot {req.robot!r}: this service's bridge drives robot {robot_id!r}")
    state = svc.bridge.measured_state() if hasattr(svc.bridge, "measured_state") else None
    if state is None:
        why = getattr(svc.bridge, "reason", None)
        raise ProblemError(409, "the controller's joint state is unknown, so no recovery can be planned from it"
                                + (f": {why}" if why else ""))
    request = req.model_dump(mode="json", exclude_none=True)
    request["model"] = svc.settings.robot
    request["measured"] = state
    if state.get("holding") not in (None, "none"):
        held = _held_object(svc)
        if held is not None:
            request["object"] = held
    return request


def _held_object(svc: Service) -> dict[str, Any] | None:
    """The object the hands hold after an abort, from the last aborted execution: its mass and CoM from the
    plan, its pose at the trajectory index the controller last reported. None when that is not known."""
    rows, _ = svc.store.list(state="aborted", limit=1)
    if not rows:
        return None
    plan = svc.store.result(rows[0]["id"])
    if not isinstance(plan, dict) or not plan.get("trajectory") or not isinstance(plan.get("object"), dict):
        return None
    index = None
    for event in svc.store.events_after(rows[0]["id"], 0, 5000):
        payload = (event.get("data") or {}).get("payload") or {}
        if event["kind"] == "bridge" and (event.get("data") or {}).get("event") == "finished":
            index = payload.get("last_index")
    index = min(int(index or 0), len(plan["trajectory"]) - 1)
    obj = plan["object"]
    return {"name": obj.get("name"), "mass_kg": obj.get("mass_kg"), "com_local": obj.get("com_local"),
            "pose": plan["trajectory"][index]["object_pose"], "from_job": rows[0]["id"], "at_index": index}


# ------------------------------------------------------------------- reads
@router.get("", response_model=JobList, summary="List jobs, newest first", responses=problems(401, 422))
def list_jobs(
    state: JobState | None = Query(None), kind: JobKind | None = Query(None),
    submitter: str | None = Query(None, max_length=128),
    limit: int = Query(50, ge=1, le=500), offset: int = Query(0, ge=0, le=10_000_000),
    include_result: bool = Query(False, description="include each job's result document (can be large); a page "
                                                    "then holds at most the service's list_results_max jobs"),
    p: Principal = Depends(principal), svc: Service = Depends(service),
) -> Response:
    if include_result:
        limit = min(limit, svc.settings.list_results_max)
    rows, total = svc.store.list(state=state, kind=kind, submitter=submitter, limit=limit, offset=offset)
    page = JobList(jobs=[], total=total, limit=limit, offset=offset).model_dump_json()
    # Each job's stored result is spliced in as its stored text, never parsed and re-serialised.
    items = ",".join(_job_json(svc, r) if include_result else job_view(r).model_dump_json() for r in rows)
    body = page.replace('"jobs":[]', '"jobs":[' + items + "]", 1)
    return Response(body, media_type="application/json")


@router.get("/{job_id}", response_model=Job, summary="One job with its result", responses=problems(401, 404, 422))
def get_job(job_id: str,
            include_result: bool = Query(True, description="false: leave out the result (cheap polling of large plans)"),
            p: Principal = Depends(principal), svc: Service = Depends(service)) -> Response:
    row = _load(svc, job_id)
    if not include_result:
        return Response(job_view(row).model_dump_json(), media_type="application/json")
    return _job_response(svc, row)


#: Largest event id a client may name (the store's ids are 63-bit integers).
MAX_EVENT_ID = 2**62


def _last_event_id(header: str | None) -> int:
    """The ``Last-Event-ID`` header as an event id; 400 for anything but a decimal id in range."""
    if header is None or header == "":
        return 0
    value = header.strip()
    if not value.isascii() or not value.isdigit() or len(value) > 19 or int(value) > MAX_EVENT_ID:
        raise ProblemError(400, f"Last-Event-ID must be an event id from this stream (a decimal integer up to "
                                f"{MAX_EVENT_ID}); got {value[:32]!r}")
    return int(value)


class StreamSlots:
    """Open event streams per user in this API process, bounded per user."""

    def __init__(self) -> None:
        self._open: dict[str, int] = {}

    def acquire(self, user: str, limit: int) -> bool:
        if self._open.get(user, 0) >= limit:
            return False
        self._open[user] = self._open.get(user, 0) + 1
        return True

    def release(self, user: str) -> None:
        left = self._open.get(user, 0) - 1
        if left > 0:
            self._open[user] = left
        else:
            self._open.pop(user, None)


def _sse(event: dict[str, Any]) -> str:
    payload = {"id": event["id"], "job_id": event["job_id"], "at": event["at"].isoformat(), "kind": event["kind"],
               "state": event.get("state"), "progress": event.get("progress"), "message": event.get("message"),
               "data": event.get("data") or {}}
    return f"id: {event['id']}\nevent: {event['kind']}\ndata: {json.dumps(payload, separators=(',', ':'))}\n\n"


@router.get(
    "/{job_id}/events", summary="Stream the job's events (Server-Sent Events)",
    response_class=StreamingResponse,
    responses={200: {"description": "text/event-stream of JobEvent objects (event: state | progress | note | approval "
                                    "| bridge); the stream ends after a terminal state",
                     "content": {"text/event-stream": {"schema": {"type": "string"}}}},
               **problems(401, 404, 422)},
)
async def job_events(
    job_id: str, request: Request,
    after: int = Query(0, ge=0, le=2**62, description="only events with a larger id (also Last-Event-ID)"),
    last_event_id: str | None = Header(None, alias="Last-Event-ID", max_length=1024),
    follow: bool = Query(True, description="keep the stream open for new events (false: send the history and end)"),
    p: Principal = Depends(principal), svc: Service = Depends(service),
) -> StreamingResponse:
    await run_in_threadpool(_load, svc, job_id)
    cursor = max(after, _last_event_id(last_event_id))
    streams: StreamSlots = svc.extra.setdefault("streams", StreamSlots())
    if not streams.acquire(p.user, svc.settings.user_stream_limit):
        raise ProblemError(429, f"user {p.user!r} holds {svc.settings.user_stream_limit} open event streams, the limit "
                                "per user; close one (or read with follow=false) and retry",
                           headers={"Retry-After": str(svc.settings.retry_after_s)})

    async def stream() -> AsyncIterator[str]:
        try:
            async for chunk in _events(cursor):
                yield chunk
        finally:
            streams.release(p.user)

    async def _events(cursor: int) -> AsyncIterator[str]:
        yield "retry: 1000\n\n"
        last_sent = time.monotonic()
        while True:
            events = await run_in_threadpool(svc.store.events_after, job_id, cursor, EVENT_PAGE)
            finished = False
            for event in events:
                cursor = event["id"]
                yield _sse(event)
                last_sent = time.monotonic()
                if event["kind"] == "state" and event.get("state") in TERMINAL_STATES:
                    finished = True
            if finished or (not follow and len(events) < EVENT_PAGE):
                return
            if not events:
                if await request.is_disconnected():
                    return
                if time.monotonic() - last_sent > svc.settings.sse_keepalive_s:
                    yield ": keep-alive\n\n"
                    last_sent = time.monotonic()
                await asyncio.sleep(svc.settings.sse_poll_s)

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


# ----------------------------------------------------------------- actions
@router.post("/{job_id}/cancel", status_code=202, response_model=Job, summary="Cancel a job (before dispatch)",
             responses=problems(400, 401, 403, 404, 409, 413, 422))
def cancel(job_id: str, body: ReasonBody | None = Body(None), p: Principal = Depends(principal),
           svc: Service = Depends(service)) -> Response:
    row = _load(svc, job_id)
    if row["submitter"] != p.user and not p.has("admin"):
        raise ProblemError(403, f"only the submitter ({row['submitter']}) or an admin can cancel job {job_id}")
    if row["state"] not in CANCELABLE_STATES:
        hint = "; use /stop to stop an execution" if row["state"] in EXECUTION_STATES else ""
        raise ProblemError(409, f"job {job_id} is {row['state']}: only queued, planning, planned or approved jobs "
                                f"can be canceled{hint}")
    try:
        row = svc.store.request_cancel(job_id, p.user, body.reason if body else None)
    except Conflict as exc:
        raise ProblemError(409, str(exc)) from None
    if svc.runner is not None and row["state"] == "planning":
        svc.runner.nudge()  # an embedded runner stops it now, not at its next flag poll
    return _job_response(svc, row, 202)


def _refuse_comparison(svc: Service, row: dict[str, Any], action: str) -> None:
    """409 for a comparison job (planned below the safety policy's floor): it never reaches the robot."""
    if row.get("comparison"):
        raise ProblemError(409, f"job {row['id']} is a comparison: it was planned below the {svc.policy.margin_floor_m * 1000:.1f} "
                                f"mm floor of the {svc.policy.describe()}, so it is never {action}; plan the task at the "
                                "floor or above to send it to the robot")


@router.post("/{job_id}/approve", response_model=Job, summary="Approve a planned job (two-person rule)",
             responses=problems(400, 401, 403, 404, 409, 413, 422))
def approve(job_id: str, body: ApproveBody | None = Body(None), p: Principal = Depends(principal),
            svc: Service = Depends(service)) -> Response:
    require("approver", p, "approving a plan")
    row = _load(svc, job_id)
    if row["submitter"] == p.user:
        raise ProblemError(403, f"two-person rule: {p.user} submitted job {job_id} and cannot approve it; "
                                "another approver must")
    if row["kind"] not in ("plan", "recover"):
        raise ProblemError(409, f"job {job_id} is a {row['kind']} job; only plan and recover jobs are approved")
    _refuse_comparison(svc, row, "approved")
    if row["state"] != "planned":
        raise ProblemError(409, f"job {job_id} is {row['state']}; only a planned job can be approved")
    sha = row["plan_sha256"]
    if body is not None and body.plan_sha256 is not None and body.plan_sha256 != sha:
        raise ProblemError(409, f"the approval names plan {body.plan_sha256} but job {job_id} holds plan {sha}; "
                                "review the current plan and approve its hash")
    now = datetime.now(timezone.utc)
    expires = now + timedelta(seconds=svc.settings.approval_ttl_s)
    approval = {"approved_by": p.user, "approved_at": now.isoformat(), "expires_at": expires.isoformat(),
                "plan_sha256": sha, "comment": body.comment if body else None}
    ok = svc.store.transition(job_id, ["planned"], "approved",
                              message=f"approved by {p.user} until {expires.isoformat(timespec='seconds')}",
                              event_kind="state", data={"approval": approval},
                              approved_by=p.user, approved_at=now, approval_expires_at=expires,
                              approved_sha256=sha, approval_comment=body.comment if body else None)
    if not ok:
        raise ProblemError(409, f"job {job_id} changed state while approving; reload it")
    return _job_response(svc, svc.store.get(job_id) or row)


@router.post("/{job_id}/reject", response_model=Job, summary="Reject a planned or approved job, saying why",
             openapi_extra={"requestBody": {"required": True}},
             responses=problems(400, 401, 403, 404, 409, 413, 422))
def reject(job_id: str, body: RejectBody | None = Body(None), p: Principal = Depends(principal),
           svc: Service = Depends(service)) -> Response:
    require("approver", p, "rejecting a plan")
    if body is None:
        raise ProblemError(422, 'a rejection needs a reason: send {"reason": "why the plan is declined"}')
    row = _load(svc, job_id)
    if row["submitter"] == p.user:
        raise ProblemError(403, f"two-person rule: {p.user} submitted job {job_id} and cannot review it")
    if row["state"] not in ("planned", "approved"):
        raise ProblemError(409, f"job {job_id} is {row['state']}; only a planned or approved job can be rejected")
    reason = body.reason.strip()
    ok = svc.store.transition(job_id, ["planned", "approved"], "rejected", message=f"rejected by {p.user}: {reason}",
                              error={"code": "REJECTED", "message": f"rejected by {p.user}: {reason}"},
                              data={"by": p.user, "reason": reason})
    if not ok:
        raise ProblemError(409, f"job {job_id} changed state while rejecting; reload it")
    return _job_response(svc, svc.store.get(job_id) or row)


@router.post("/{job_id}/dispatch", status_code=202, response_model=Job,
             summary="Send an approved plan to the robot (through the safety gate); answers with the job's summary, "
                     "no plan body",
             responses=problems(400, 401, 403, 404, 409, 413, 422))
def dispatch(job_id: str, p: Principal = Depends(principal), svc: Service = Depends(service)) -> Response:
    require("operator", p, "dispatching a plan")
    row = _load(svc, job_id)
    _refuse_comparison(svc, row, "dispatched")
    if row["state"] == "planned" and row["kind"] in ("plan", "recover"):
        raise ProblemError(409, f"job {job_id} is planned but not approved (or its approval expired); "
                                "an approver must approve it first")
    if row["state"] != "approved":
        raise ProblemError(409, f"job {job_id} is {row['state']}; only an approved plan can be dispatched")
    text = svc.store.result_text(job_id)
    # The stored text is the plan's canonical JSON (service.jobs.results), so its hash is the plan's hash.
    if text is None or hashlib.sha256(text.encode("utf-8")).hexdigest() != row["approved_sha256"]:
        raise ProblemError(409, f"the stored plan of job {job_id} no longer matches the approved hash "
                                f"{row['approved_sha256']}; it cannot be dispatched")
    # The policy's physics dry run: the card's, bound to the plan's hash; its report goes on to the bridge's gate.
    physics, physics_report = dispatch_physics(svc, row)
    if physics is not None:
        raise ProblemError(409, f"job {job_id} is not dispatched: {physics}")
    signing = getattr(svc.bridge, "signing_problem", None)
    if signing is not None:
        raise ProblemError(409, f"the robot bridge cannot sign commands: {signing}; the controller refuses unsigned "
                                "commands, so nothing is dispatched")
    if not svc.bridge.controller_alive():
        why = getattr(svc.bridge, "reason", None)
        raise ProblemError(409, "no controller is alive" + (f": {why}" if why else "")
                           + "; start the controller and retry")
    # One dispatch at a time per robot, decided in the job store. The canonical text goes down as it is:
    # the gate hashes these bytes instead of re-serialising a dict.
    try:
        began = svc.executions.begin(row, text, p.user, physics=physics_report)
    except RobotBusy as exc:
        raise ProblemError(409, f"job {exc.running_job_id} is executing on the robot; one execution at a time "
                                "(stop it or wait for it to end)") from None
    if not began:
        raise ProblemError(409, f"job {job_id} changed state before dispatch (approval expired or acted on); reload it")
    # The job's summary only: the plan (megabytes) is already with the client that approved it.
    return Response(job_view(svc.store.get(job_id) or row).model_dump_json(exclude={"result"}), status_code=202,
                    media_type="application/json")


@router.post("/{job_id}/stop", status_code=202, response_model=Job, summary="Stop an execution now",
             responses=problems(400, 401, 403, 404, 409, 413, 422))
def stop(job_id: str, body: ReasonBody | None = Body(None), p: Principal = Depends(principal),
         svc: Service = Depends(service)) -> Response:
    require("operator", p, "stopping an execution")
    row = _load(svc, job_id)
    if row["state"] not in EXECUTION_STATES:
        raise ProblemError(409, f"job {job_id} is {row['state']}; only a dispatching or executing job can be stopped")
    svc.executions.stop(job_id, p.user)
    return _job_response(svc, svc.store.get(job_id) or row, 202)


#: Bytes per read when serving an audit file.
AUDIT_CHUNK_BYTES = 1 << 20


def _snapshot(path: str) -> tuple[Iterator[bytes], int]:
    """The file's bytes as they are now, and their count.

    The audit writer only appends, so the first ``size`` bytes never change; serving exactly
    those keeps the body equal to the Content-Length while a live job's file grows (a plain
    file response declared the size at stat time and then sent more, and the connection broke).
    """
    f = open(path, "rb")  # noqa: SIM115 - closed by the generator
    size = os.fstat(f.fileno()).st_size

    def chunks() -> Iterator[bytes]:
        with f:
            left = size
            while left > 0:
                block = f.read(min(left, AUDIT_CHUNK_BYTES))
                if not block:
                    break
                left -= len(block)
                yield block

    return chunks(), size


@router.get(
    "/{job_id}/audit", summary="The job's MCAP audit file (the bytes written so far, for a live job)",
    response_class=StreamingResponse,
    responses={200: {"description": "MCAP file", "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}},
               **problems(401, 404, 422)},
)
def audit(job_id: str, p: Principal = Depends(principal), svc: Service = Depends(service)) -> StreamingResponse:
    row = _load(svc, job_id)
    path = row.get("audit_path")
    if not path or not Path(path).is_file():
        raise ProblemError(404, f"no audit file for job {job_id}" + ("" if svc.auditor else " (this process runs no audit writer)"))
    body, size = _snapshot(path)
    headers = {"X-Audit-Head": row.get("audit_head") or "", "Content-Length": str(size),
               "Content-Disposition": f'attachment; filename="{job_id}.mcap"'}
    return StreamingResponse(body, media_type="application/octet-stream", headers=headers)
