"""The code that runs a job inside a worker: a local spawn process or a Ray actor.

:class:`JobHandlers` is the one piece both kinds of worker use: it resolves the
handler table and loads the robot model once when the worker starts, and maps
everything a handler can do (return, poll a cancel, raise) to one outcome
``(tag, value)``: ``("done", packaged result)``, ``("canceled", None)`` or
``("error", {"code", "message", ...})``. The executors turn an outcome into an
:class:`~service.executors.base.ExecEvent` with ``outcome_event``.

A local worker (:func:`worker_main`) runs jobs one at a time for as long as its
parent lives: it receives ``(job_id, kind, request)`` on its pipe, calls the
handler with a context whose ``cancelled()`` reads a shared event, and sends
progress and the outcome back. It never touches the job store: the parent
runner is the only writer, so a worker that is killed cannot leave a half-written row.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import traceback
from multiprocessing.connection import Connection
from multiprocessing.synchronize import Event
from typing import Any

from pydantic import ValidationError

from planner.api.jobs import JobContext, declare_fork_benign

from .handlers import CANCELED_TYPES, HandlerError, JobCanceled, resolve
from .results import InvalidResult, package

#: Progress messages are sent at most this often (the runner stores them even less often).
PROGRESS_MIN_INTERVAL_S = 0.05
#: How often the worker checks that its parent is still alive.
PARENT_CHECK_S = 0.2

Outcome = tuple[str, Any]


def lower_priority(nice: int) -> None:
    """Planning yields the CPU to the API process, so submit and poll stay fast while every worker plans."""
    if nice:
        try:
            os.nice(nice)
        except OSError:
            pass


#: The message of an unexpected failure; its details (type, traceback) go to the worker's log only.
INTERNAL_ERROR_MESSAGE = "the planner failed with an internal error; the service log has the details"


def failure_of(exc: BaseException) -> dict[str, Any]:
    """A job's error from an exception: a usage error keeps its own message, anything else a generic one.

    The message is what every user of the job reads, so it never carries an exception's class
    name or a traceback (which can quote code and data); those are logged.
    """
    if isinstance(exc, ValidationError):
        from ..api.problems import clean_message

        lines = [f"{'.'.join(str(p) for p in e['loc']) or 'value'}: {clean_message(e['msg'])}" for e in exc.errors()[:10]]
        return {"code": "INVALID_REQUEST", "message": "the request is invalid: " + "; ".join(lines)}
    if isinstance(exc, (ValueError, LookupError)):
        message = str(exc).strip() or "the request cannot be run as given"
        return {"code": "INVALID_REQUEST", "message": message[:2000]}
    logging.getLogger("regrasp.worker").error("job failed: %s: %s\n%s", type(exc).__name__, exc,
                                              traceback.format_exc(limit=8))
    return {"code": "ERROR", "message": INTERNAL_ERROR_MESSAGE}


class JobHandlers:
    """The handler table of one worker, with the robot model loaded once for the worker's life."""

    def __init__(self, handlers: dict[str, str], robot: str | None) -> None:
        self.table: dict[str, Any] = {}
        self.errors: dict[str, str] = {}
        for kind, target in handlers.items():
            try:
                self.table[kind] = resolve(target)
            except Exception as exc:  # noqa: BLE001 - reported with each job of that kind; the worker stays up
                self.errors[kind] = str(exc) if isinstance(exc, HandlerError) else f"job handler {target!r}: {exc!r}"
        if robot:
            from planner.api.robots import load_robot

            load_robot(robot)  # cached for the life of the process: handlers reuse it
            try:
                from planner.api.robots import warm_up

                warm_up(robot)  # the compiled kernels ready before the first job's time limit starts
            except Exception:  # an optimisation: a real fault shows again in the job that meets it
                logging.getLogger("regrasp.worker").warning("planner warm-up failed; kernels compile in the first job",
                                                            exc_info=True)

    def run(self, kind: str, request: dict[str, Any], ctx: JobContext) -> Outcome:
        """Run one job to its outcome; never raises (every failure becomes the job's error)."""
        try:
            if kind not in self.table:
                raise LookupError(self.errors.get(kind) or f"no handler for job kind {kind!r}")
            if ctx.cancelled():
                raise JobCanceled("canceled before start")
            result = self.table[kind](request, ctx)
            if ctx.cancelled() and result is None:
                raise JobCanceled("canceled")
            packaged = package(result)
            if kind == "plan" and packaged["summary"].get("status") == "solved":
                from .risk import (
                    safe_risk_card,  # the gate's dry run, where the plan is (not in the API process)
                )

                packaged["summary"]["risk"] = safe_risk_card(result, packaged["text"])
            return "done", packaged
        except CANCELED_TYPES:
            return "canceled", None
        except InvalidResult as exc:
            return "error", {"code": "INVALID_RESULT", "message": str(exc)}
        except Exception as exc:  # noqa: BLE001 - every failure becomes the job's error
            return "error", failure_of(exc)


class WorkerContext:
    """The ``ctx`` of a job in a local worker: progress goes down the pipe, cancel is a shared event."""

    def __init__(self, conn: Connection, job_id: str, cancel: Event, lock: threading.Lock) -> None:
        self._conn = conn
        self._job_id = job_id
        self._cancel = cancel
        self._lock = lock
        self._last = 0.0

    def progress(self, fraction: float, message: str) -> None:
        now = time.monotonic()
        if now - self._last < PROGRESS_MIN_INTERVAL_S and fraction < 1.0:
            return
        self._last = now
        fraction = min(1.0, max(0.0, float(fraction)))
        with self._lock:
            try:
                self._conn.send(("progress", self._job_id, fraction, str(message)[:500]))
            except (BrokenPipeError, EOFError, OSError):
                os._exit(3)  # the parent is gone: stop planning at once

    def cancelled(self) -> bool:
        return self._cancel.is_set()


def die_with_parent() -> None:
    """Ask Linux to SIGKILL this process the moment its parent dies (``PR_SET_PDEATHSIG``): a kill -9 of the
    server then takes its workers at once; elsewhere the parent watch (:func:`_watch_parent`) does it."""
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _watch_parent(parent_pid: int) -> None:
    """Exit at once when the parent dies (SIGKILL of the server must not leave planners running)."""
    while True:
        if os.getppid() != parent_pid:
            os._exit(3)
        time.sleep(PARENT_CHECK_S)


def worker_main(conn: Connection, cancel: Event, handlers: dict[str, str], robot: str | None, parent_pid: int,
                nice: int = 0) -> None:
    """Entry point of a local worker process."""
    die_with_parent()
    if os.getppid() != parent_pid:  # the parent died before the request above
        os._exit(3)
    lower_priority(nice)
    watch = threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="parent-watch")
    watch.start()
    declare_fork_benign(watch)  # the planner may still fork its helpers (survey workers, motion hops) here
    jobs = JobHandlers(handlers, robot)
    lock = threading.Lock()
    conn.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        job_id, kind, request = msg
        tag, value = jobs.run(kind, request, WorkerContext(conn, job_id, cancel, lock))
        with lock:
            try:
                conn.send((tag, job_id, value))
            except (BrokenPipeError, EOFError, OSError):
                os._exit(3)  # the parent is gone; nobody is waiting for this result
