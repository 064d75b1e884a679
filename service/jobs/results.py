"""Packaging a job's result where it was computed (worker process or Ray actor), not in the API process.

A plan can be 10 MB of JSON. The worker validates it against the contract's
model, serialises it once in canonical form (docs/contract.md section 3), hashes it,
and sends the text with a small summary; the runner stores the text as is and
the API serves it verbatim. So the API process never parses, re-serialises or
hashes a large plan, and the stored bytes are exactly the ones the hash covers.
"""

from __future__ import annotations

import hashlib
from typing import Any

from pydantic import ValidationError

from schemas.plan import PLAN_SCHEMA, Plan, canonical_json
from schemas.survey import SURVEY_SCHEMA, Survey
from service.errors import RegraspServiceError


class InvalidResult(RegraspServiceError, ValueError):
    """The handler returned something that is not a valid result document."""


def _validate(result: dict[str, Any]) -> None:
    model = {PLAN_SCHEMA: Plan, SURVEY_SCHEMA: Survey}.get(str(result.get("schema")))
    if model is None:
        return
    try:
        model.model_validate(result)
    except ValidationError as exc:
        first = "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors()[:5])
        raise InvalidResult(f"the {result['schema']} document breaks the contract: {first}") from None


def summarize(result: dict[str, Any]) -> dict[str, Any]:
    """The few fields the runner needs to decide the job's state and provenance."""
    scenario = result.get("scenario") if isinstance(result.get("scenario"), dict) else {}
    robot = result.get("robot") if isinstance(result.get("robot"), dict) else {}
    failure = result.get("failure") if isinstance(result.get("failure"), dict) else None
    seed = result.get("seed") if isinstance(result.get("seed"), int) else scenario.get("seed")
    return {
        "status": result.get("status"),
        "failure": {"code": str(failure.get("code") or "INFEASIBLE"), "message": str(failure.get("message") or "")}
        if failure else None,
        "seed": seed if isinstance(seed, int) else None,
        "robot": robot.get("name"),
        "robot_sha256": robot.get("urdf_sha256"),
        "threshold_m": result.get("threshold_m") if isinstance(result.get("threshold_m"), (int, float)) else None,
    }


def package(result: Any) -> dict[str, Any]:
    """Validate, serialise canonically and hash a handler's result: ``{"text", "sha256", "summary"}``."""
    if not isinstance(result, dict):
        raise InvalidResult(f"the handler returned {type(result).__name__}, not a JSON object")
    _validate(result)
    try:
        raw = canonical_json(result)
    except (TypeError, ValueError) as exc:
        raise InvalidResult(f"the result is not canonical JSON (NaN/Inf or non-JSON values): {exc}") from None
    return {"text": raw.decode("utf-8"), "sha256": hashlib.sha256(raw).hexdigest(), "summary": summarize(result)}
