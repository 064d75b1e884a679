"""``GET /v1/jobs/{id}/risk``: the plan's risk card, the gate's verdict at dispatch, the 0 mm comparison.

The card (service.jobs.risk) is made in the worker when the plan is made and stored with the job's
``planned`` event; a job planned without one (another handler, an older service) gets it on
the first request, stored then as a ``note`` event, so it is computed once per plan.
"""

from __future__ import annotations

import json
from typing import Any, Iterator

from fastapi import APIRouter, Depends, Path
from fastapi.concurrency import run_in_threadpool

from schemas.common import OpenModel

from ..context import Service
from ..jobs.risk import compare_with_unconstrained, safe_risk_card
from .auth import Principal
from .deps import principal, problems, service
from .problems import ProblemError

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
#: Events read per query while looking for the card and the gate's verdict.
EVENT_PAGE = 500
#: Recent plan jobs searched for the same task planned at 0 mm.
ZERO_MM_SEARCH = 200
#: States in which a job holds its solved plan.
HAS_PLAN = frozenset({"planned", "approved", "dispatching", "executing", "succeeded", "aborted", "rejected"})


class RiskReport(OpenModel):
    """The risk card at planning time, the gate's verdict at dispatch (if dispatched), the 0 mm comparison."""

    job_id: str
    planning: dict[str, Any] | None = None
    dispatch: dict[str, Any] | None = None
    unconstrained: dict[str, Any] | None = None


def _events(svc: Service, job_id: str) -> Iterator[dict[str, Any]]:
    cursor = 0
    while True:
        page = svc.store.events_after(job_id, cursor, EVENT_PAGE)
        yield from page
        if len(page) < EVENT_PAGE:
            return
        cursor = page[-1]["id"]


def _plan(svc: Service, job_id: str) -> tuple[dict[str, Any] | None, str | None]:
    text = svc.store.result_text(job_id)
    if text is None:
        return None, None
    plan = json.loads(text)
    return (plan, text) if isinstance(plan, dict) and plan.get("status") == "solved" else (None, None)


def _segment(plan: dict[str, Any] | None, point: Any) -> dict[str, Any] | None:
    if plan is None or not isinstance(point, int):
        return None
    for i, seg in enumerate(plan.get("segments") or []):
        if seg.get("first", 0) <= point <= seg.get("last", -1):
            return {"index": i, "kind": seg.get("kind"), "hand": seg.get("hand")}
    return None


def _report(svc: Service, job_id: str) -> RiskReport:
    row = svc.store.get(job_id) if len(job_id) <= 64 else None
    if row is None:
        raise ProblemError(404, f"no job with id {job_id[:64]!r}")
    if row["kind"] != "plan":
        raise ProblemError(409, f"job {job_id} is a {row['kind']} job; only plan jobs have a risk card")
    card = verdict = None
    for ev in _events(svc, job_id):
        data = ev.get("data") or {}
        if card is None and isinstance(data.get("risk"), dict) and data["risk"].get("plan_sha256") in (row["plan_sha256"], None):
            card = data["risk"]
        payload = data.get("payload") if ev["kind"] == "bridge" and data.get("event") == "gate" else None
        if isinstance(payload, dict) and "passed" in payload:
            verdict = payload  # the last one: a re-dispatch after an expired approval checks again
        elif isinstance(data.get("verdict"), dict) and verdict is None:
            verdict = data["verdict"]
    plan: dict[str, Any] | None = None
    if card is None and row["state"] in HAS_PLAN and row["plan_sha256"]:
        plan, text = _plan(svc, job_id)
        if plan is not None:
            card = safe_risk_card(plan, text)
            svc.store.add_event(job_id, "note", message="risk card (gate dry run)", data={"risk": card})
    report = RiskReport(job_id=job_id, planning=card)
    if verdict is not None:
        if not verdict.get("passed") and plan is None:
            plan, _ = _plan(svc, job_id)
        report.dispatch = {k: verdict.get(k) for k in ("passed", "check", "message", "sample_index", "point_index", "t",
                                                        "threshold_m", "samples")}
        report.dispatch["segment"] = _segment(plan, verdict.get("point_index"))
    report.unconstrained = _unconstrained(svc, row, plan)
    return report


def _unconstrained(svc: Service, row: dict[str, Any], plan: dict[str, Any] | None) -> dict[str, Any] | None:
    """The same request planned at 0 mm, if the store holds it: the newest such solved plan."""
    request = dict(row["request"] or {})
    if request.get("threshold_m") == 0:
        return None
    want = {k: v for k, v in request.items() if k not in ("threshold_m", "time_limit_s")}
    rows, _ = svc.store.list(kind="plan", limit=ZERO_MM_SEARCH, offset=0)
    for other in rows:
        req = dict(other["request"] or {})
        if other["id"] == row["id"] or req.get("threshold_m") != 0 or other["state"] not in HAS_PLAN:
            continue
        if {k: v for k, v in req.items() if k not in ("threshold_m", "time_limit_s")} != want:
            continue
        free, _ = _plan(svc, other["id"])
        if free is None:
            continue
        if plan is None:
            plan, _ = _plan(svc, row["id"])
        if plan is None:
            return None
        return {"job_id": other["id"], **compare_with_unconstrained(plan, free)}
    return None


@router.get("/{job_id}/risk", response_model=RiskReport, summary="The plan's risk card and the gate's verdicts",
            responses=problems(401, 404, 409, 422))
async def job_risk(job_id: str = Path(..., max_length=64), p: Principal = Depends(principal),
                   svc: Service = Depends(service)) -> RiskReport:
    return await run_in_threadpool(_report, svc, job_id)
