"""Entry points the service's workers call: one function per job kind.

A worker process calls ``run_plan(request, ctx)`` or ``run_survey(request, ctx)``
with the job's request (docs/contract.md section 5) and a context that reports
progress and tells whether the job was cancelled. They return the plan or survey
document (docs/contract.md sections 3 and 4) as a JSON-ready dict.
"""

from __future__ import annotations

from typing import Any, Protocol


class JobContext(Protocol):
    def progress(self, fraction: float, message: str) -> None:
        """Report progress in [0, 1] with a short human-readable message."""

    def cancelled(self) -> bool:
        """True once the job was asked to stop; long loops poll it and raise :class:`Canceled`."""


class Canceled(Exception):
    """Raised inside planning when the job context says the job was cancelled."""


def run_plan(request: dict[str, Any], ctx: JobContext) -> dict[str, Any]:
    from .jobs import plan_job

    return plan_job(_named_only(request), ctx)


def run_survey(request: dict[str, Any], ctx: JobContext) -> dict[str, Any]:
    from .jobs import survey_job

    return survey_job(_named_only(request), ctx)


def _named_only(request: dict[str, Any]) -> dict[str, Any]:
    """The request with every name checked and a named scenario resolved: no request string becomes a path."""
    from .jobs import PlanningInputError
    from .request_names import RequestNameError, resolve_request

    try:
        return resolve_request(request)
    except RequestNameError as exc:
        raise PlanningInputError(str(exc)) from None
