"""The executor interface the runner drives, whatever runs the jobs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Protocol

EventKind = Literal["progress", "done", "error", "canceled"]


@dataclass
class ExecEvent:
    """Something that happened to a running job: progress, its result, an error, or its stop after a cancel."""

    job_id: str
    kind: EventKind
    fraction: float = 0.0
    message: str = ""
    result: dict[str, Any] | None = None
    error: dict[str, Any] | None = None


def outcome_event(job_id: str, tag: str, value: Any) -> ExecEvent:
    """The event of a job's outcome as a worker reports it (service.jobs.worker_process.JobHandlers.run)."""
    if tag == "done":
        return ExecEvent(job_id, "done", result=value)
    if tag == "canceled":
        return ExecEvent(job_id, "canceled", message="stopped after a cancel")
    return ExecEvent(job_id, "error", error=value)


def crashed_event(job_id: str, reason: str) -> ExecEvent:
    """The job's worker died under it: the job fails with the reason (never stays stuck in planning)."""
    return ExecEvent(job_id, "error", error={"code": "WORKER_CRASHED", "message": reason})


class Executor(Protocol):
    """Runs jobs; the runner claims them from the store and feeds them in."""

    name: str

    def free_slots(self) -> int:
        """How many more jobs can start now (only slots whose worker is ready count)."""

    def total_slots(self) -> int:
        """Configured parallelism."""

    def start(self, job_id: str, kind: str, request: dict[str, Any]) -> str:
        """Start a job on a free slot; returns a description of where it runs (e.g. ``local pid 123``)."""

    def cancel(self, job_id: str) -> None:
        """Ask the job to stop; if it has not stopped after the grace period, kill its worker."""

    def poll(self, timeout: float) -> list[ExecEvent]:
        """Wait up to ``timeout`` s and return what happened since the last call."""

    def close(self) -> None:
        """Stop every worker."""
