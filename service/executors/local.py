"""Killable local worker processes (multiprocessing spawn), one job at a time each.

Each slot owns one process, a duplex pipe and a cancel event. A cancel sets the
event (the planner polls ``ctx.cancelled()``); a worker that has not stopped
``cancel_grace_s`` later is killed and replaced, so a cancel or a timeout always
takes effect within a bounded time even if the handler never polls.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

from ..jobs.worker_process import worker_main
from ..settings import ServiceSettings
from .base import ExecEvent, crashed_event, outcome_event


@dataclass
class _Slot:
    index: int
    process: Any = None
    conn: Connection | None = None
    cancel: Any = None
    ready: bool = False
    job_id: str | None = None
    kill_at: float | None = None


def _describe_exit(code: int | None) -> str:
    if code is None:
        return "no exit code"
    if code < 0:
        try:
            return f"killed by signal {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class LocalExecutor:
    """``settings.workers`` spawn processes on this machine."""

    name = "local"

    def __init__(self, settings: ServiceSettings) -> None:
        self.settings = settings
        self._ctx = mp.get_context("spawn")
        self._slots = [_Slot(i) for i in range(settings.workers)]
        for slot in self._slots:
            self._spawn(slot)

    # ------------------------------------------------------------- processes
    def _spawn(self, slot: _Slot) -> None:
        parent, child = self._ctx.Pipe(duplex=True)
        slot.cancel = self._ctx.Event()
        robot = self.settings.robot if self.settings.preload_robot else None
        slot.process = self._ctx.Process(
            target=worker_main, args=(child, slot.cancel, dict(self.settings.handlers), robot, os.getpid(), self.settings.worker_nice),
            name=f"regrasp-worker-{slot.index}", daemon=True,
        )
        slot.process.start()
        child.close()
        slot.conn, slot.ready, slot.job_id, slot.kill_at = parent, False, None, None

    def _kill(self, slot: _Slot) -> None:
        if slot.process is not None and slot.process.is_alive():
            slot.process.kill()
        if slot.process is not None:
            slot.process.join(timeout=2)
        if slot.conn is not None:
            slot.conn.close()

    def _retire(self, slot: _Slot) -> None:
        """Kill the slot's process and leave the slot empty; the next ``poll`` spawns its replacement.

        Spawning waits for a new interpreter to start; doing it on the next poll lets the runner
        record the job's outcome first, so a kill lands in the job's state as soon as it happens.
        """
        self._kill(slot)
        slot.process, slot.conn, slot.ready, slot.job_id, slot.kill_at = None, None, False, None, None

    # ------------------------------------------------------------- interface
    def total_slots(self) -> int:
        return len(self._slots)

    def free_slots(self) -> int:
        return sum(1 for s in self._slots if s.ready and s.job_id is None)

    def start(self, job_id: str, kind: str, request: dict[str, Any]) -> str:
        for slot in self._slots:
            if slot.ready and slot.job_id is None:
                slot.cancel.clear()
                slot.job_id, slot.kill_at = job_id, None
                assert slot.conn is not None
                slot.conn.send((job_id, kind, request))
                return f"local worker pid {slot.process.pid}"
        raise RuntimeError("no free worker slot")

    def cancel(self, job_id: str) -> None:
        for slot in self._slots:
            if slot.job_id == job_id and slot.kill_at is None:
                slot.cancel.set()
                slot.kill_at = time.monotonic() + self.settings.cancel_grace_s

    def poll(self, timeout: float) -> list[ExecEvent]:
        events: list[ExecEvent] = []
        for slot in self._slots:
            if slot.process is None:
                self._spawn(slot)
        waitables: list[Any] = []
        for slot in self._slots:
            if slot.conn is not None:
                waitables.append(slot.conn)
            if slot.process is not None:
                waitables.append(slot.process.sentinel)
        kill_times = [s.kill_at for s in self._slots if s.kill_at is not None]
        if kill_times:  # wake for the earliest kill, not up to a whole poll period after it
            timeout = max(0.0, min(timeout, min(kill_times) - time.monotonic()))
        ready = set(wait(waitables, timeout=timeout)) if waitables else set()
        for slot in self._slots:
            if slot.conn is not None and slot.conn in ready:
                self._drain(slot, events)
            if slot.process is not None and not slot.process.is_alive():
                self._drain(slot, events)
                self._on_death(slot, events)
            elif slot.kill_at is not None and time.monotonic() >= slot.kill_at and slot.job_id is not None:
                job_id = slot.job_id
                self._retire(slot)
                events.append(ExecEvent(job_id, "canceled", message="worker killed: it did not stop within the grace period"))
        return events

    def _drain(self, slot: _Slot, events: list[ExecEvent]) -> None:
        conn = slot.conn
        while conn is not None:
            try:
                if not conn.poll():
                    return
                msg = conn.recv()
            except (EOFError, OSError):
                return
            tag = msg[0]
            if tag == "ready":
                slot.ready = True
            elif tag == "progress":
                if msg[1] == slot.job_id:
                    events.append(ExecEvent(msg[1], "progress", fraction=msg[2], message=msg[3]))
            elif msg[1] == slot.job_id:
                slot.job_id, slot.kill_at = None, None
                events.append(outcome_event(msg[1], tag, msg[2]))

    def _on_death(self, slot: _Slot, events: list[ExecEvent]) -> None:
        code = slot.process.exitcode
        if slot.job_id is not None:
            events.append(crashed_event(
                slot.job_id, f"worker process {slot.process.pid} died ({_describe_exit(code)}) while running the job"))
        self._retire(slot)

    def close(self) -> None:
        for slot in self._slots:
            try:
                if slot.conn is not None and slot.job_id is None:
                    slot.conn.send(None)
            except OSError:
                pass
        deadline = time.monotonic() + 1.0
        for slot in self._slots:
            if slot.process is not None:
                slot.process.join(timeout=max(0.0, deadline - time.monotonic()))
            self._kill(slot)
