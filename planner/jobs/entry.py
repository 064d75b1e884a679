"""Entry points the service's workers call: one function per job kind.

A worker process calls ``run_plan``, ``run_survey`` or ``run_recover`` with the job's
request (docs/contract.md section 5) and a context that reports progress and
tells whether the job was cancelled. They return the plan or survey document as a JSON-ready
dict, and raise :class:`planner.errors.Canceled` when the context asked them to stop.
"""

from __future__ import annotations

from typing import Any, Protocol

from planner.errors import Canceled, InputError
from planner.jobs.plan_job import plan_job
from planner.jobs.recovery import recover_job
from planner.jobs.request_names import RequestNameError, resolve_request
from planner.jobs.survey_job import survey_job

__all__ = ["Canceled", "JobContext", "run_plan", "run_recover", "run_survey"]


class JobContext(Protocol):
    def progress(self, fraction: float, message: str) -> None:
        """Report progress in [0, 1] with a short human-readable message."""

    def cancelled(self) -> bool:
        """True once the job was asked to stop; long loops poll it and raise :class:`Canceled`."""


def run_plan(request: dict[str, Any], ctx: JobContext) -> dict[str, Any]:
    return plan_job(_named_only(request), ctx)


def run_recover(request: dict[str, Any], ctx: JobContext) -> dict[str, Any]:
    return recover_job(request, ctx)


def run_survey(request: dict[str, Any], ctx: JobContext) -> dict[str, Any]:
    return survey_job(_named_only(request), ctx)


def _named_only(request: dict[str, Any]) -> dict[str, Any]:
    """The request with every name checked and a named scenario resolved: no request string becomes a path."""
    try:
        return resolve_request(request)
    except RequestNameError as exc:
        raise InputError(str(exc)) from None
