"""The code that runs inside one planning worker process (multiprocessing, spawn).

A worker loads the robot model once, then runs jobs one at a time for as long as
its parent lives: it receives ``(job_id, kind, request)`` on its pipe, calls the
job's handler with a context whose ``cancelled()`` reads a shared event, and
sends progress and the outcome back. It never touches the job store: the parent
runner is the only writer, so a worker that is killed cannot leave a half-written row.
"""

from __future__ import annotations

import os
import threading
import time
import traceback
from multiprocessing.connection import Connection
from multiprocessing.synchronize import Event
from typing import Any

#: Progress messages are sent at most this often (the runner stores them even less often).
PROGRESS_MIN_INTERVAL_S = 0.05
#: How often the worker checks that its parent is still alive.
PARENT_CHECK_S = 0.2


class WorkerContext:
    """The ``ctx`` handed to a job handler (planner.entry.JobContext)."""

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


def _watch_parent(parent_pid: int) -> None:
    """Exit at once when the parent dies (SIGKILL of the server must not leave planners running)."""
    while True:
        if os.getppid() != parent_pid:
            os._exit(3)
        time.sleep(PARENT_CHECK_S)


def worker_main(conn: Connection, cancel: Event, handlers: dict[str, str], robot: str | None, parent_pid: int,
                nice: int = 0) -> None:
    """Entry point of a worker process."""
    if nice:
        try:
            os.nice(nice)  # planning yields the CPU to the API process: submit/poll stay fast under load
        except OSError:
            pass
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="parent-watch").start()
    from .handlers import canceled_exception_types, resolve
    from .results import InvalidResult, package

    lock = threading.Lock()
    table: dict[str, Any] = {}
    errors: dict[str, str] = {}
    for kind, target in handlers.items():
        try:
            table[kind] = resolve(target)
        except Exception as exc:  # noqa: BLE001 - reported per job, the worker stays up
            errors[kind] = str(exc)
    if robot:
        from planner.robot_model import load_robot

        load_robot(robot)  # cached for the life of the process: handlers reuse it
    canceled_types = canceled_exception_types()
    conn.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        job_id, kind, request = msg
        ctx = WorkerContext(conn, job_id, cancel, lock)
        try:
            if kind not in table:
                raise LookupError(errors.get(kind) or f"no handler for job kind {kind!r}")
            if cancel.is_set():
                raise canceled_types[0]("canceled before start")
            result = table[kind](request, ctx)
            if cancel.is_set() and result is None:
                raise canceled_types[0]("canceled")
            outcome: tuple[Any, ...] = ("done", job_id, package(result))
        except canceled_types:
            outcome = ("canceled", job_id)
        except InvalidResult as exc:
            outcome = ("error", job_id, {"code": "INVALID_RESULT", "message": str(exc)})
        except Exception as exc:  # noqa: BLE001 - every failure becomes the job's error
            code = "INVALID_REQUEST" if isinstance(exc, (ValueError, LookupError)) else "ERROR"
            outcome = ("error", job_id, {"code": code, "message": f"{type(exc).__name__}: {exc}",
                                         "traceback": traceback.format_exc(limit=8)})
        with lock:
            try:
                conn.send(outcome)
            except (BrokenPipeError, EOFError, OSError):
                os._exit(3)  # the parent is gone; nobody is waiting for this result
