"""Run jobs on a Ray cluster through the same executor interface.

One threaded Ray actor per slot loads the robot model once and runs one job at
a time; a second actor thread answers ``cancel()`` and ``progress()`` while the
job runs, so cancel and progress work exactly as with local processes. An actor
that has not stopped ``cancel_grace_s`` after a cancel is killed
(``ray.kill``) and replaced; an actor that dies fails its job with the reason.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

from ..settings import ServiceSettings
from .base import ExecEvent

log = logging.getLogger("regrasp.ray")


class _ActorContext:
    def __init__(self, actor: "_JobActorImpl") -> None:
        self._actor = actor

    def progress(self, fraction: float, message: str) -> None:
        with self._actor.lock:
            self._actor.seq += 1
            self._actor.latest = (min(1.0, max(0.0, float(fraction))), str(message)[:500], self._actor.seq)

    def cancelled(self) -> bool:
        return self._actor.cancel_event.is_set()


class _JobActorImpl:
    """Body of the Ray actor (wrapped with ``ray.remote`` lazily, so importing this module needs no Ray)."""

    def __init__(self, handlers: dict[str, str], robot: str | None) -> None:
        from ..handlers import canceled_exception_types, resolve

        self.table: dict[str, Any] = {}
        self.errors: dict[str, str] = {}
        for kind, target in handlers.items():
            try:
                self.table[kind] = resolve(target)
            except Exception as exc:  # noqa: BLE001
                self.errors[kind] = str(exc)
        if robot:
            from planner.robot_model import load_robot

            load_robot(robot)
        self.canceled_types = canceled_exception_types()
        self.cancel_event = threading.Event()
        self.lock = threading.Lock()
        self.latest: tuple[float, str, int] | None = None
        self.seq = 0

    def ready(self) -> int:
        import os

        return os.getpid()

    def run(self, job_id: str, kind: str, request: dict[str, Any]) -> tuple[str, Any]:
        from ..results import InvalidResult, package

        self.cancel_event.clear()
        with self.lock:
            self.latest = None
        ctx = _ActorContext(self)
        try:
            if kind not in self.table:
                raise LookupError(self.errors.get(kind) or f"no handler for job kind {kind!r}")
            return "done", package(self.table[kind](request, ctx))
        except self.canceled_types:
            return "canceled", None
        except InvalidResult as exc:
            return "error", {"code": "INVALID_RESULT", "message": str(exc)}
        except Exception as exc:  # noqa: BLE001
            code = "INVALID_REQUEST" if isinstance(exc, (ValueError, LookupError)) else "ERROR"
            return "error", {"code": code, "message": f"{type(exc).__name__}: {exc}"}

    def cancel(self) -> None:
        self.cancel_event.set()

    def progress(self) -> tuple[float, str, int] | None:
        with self.lock:
            return self.latest


@dataclass
class _Slot:
    actor: Any = None
    ready_ref: Any = None
    ready: bool = False
    job_id: str | None = None
    run_ref: Any = None
    progress_ref: Any = None
    last_seq: int = 0
    kill_at: float | None = None
    pid: int | None = None


class RayExecutor:
    name = "ray"

    def __init__(self, settings: ServiceSettings) -> None:
        import ray

        self.ray = ray
        self.settings = settings
        if not ray.is_initialized():
            if settings.ray_address:
                ray.init(address=settings.ray_address, ignore_reinit_error=True, log_to_driver=False)
            else:
                ray.init(ignore_reinit_error=True, include_dashboard=False, log_to_driver=False,
                         num_cpus=max(settings.workers, 1))
        self._actor_cls = ray.remote(num_cpus=1, max_concurrency=3, max_restarts=0)(_JobActorImpl)
        self._slots = [_Slot() for _ in range(settings.workers)]
        self._lock = threading.Lock()
        for slot in self._slots:
            self._spawn(slot)

    def _spawn(self, slot: _Slot) -> None:
        robot = self.settings.robot if self.settings.preload_robot else None
        slot.actor = self._actor_cls.remote(dict(self.settings.handlers), robot)
        slot.ready_ref = slot.actor.ready.remote()
        slot.ready, slot.job_id, slot.run_ref, slot.progress_ref, slot.kill_at = False, None, None, None, None
        slot.last_seq = 0

    def total_slots(self) -> int:
        return len(self._slots)

    def free_slots(self) -> int:
        self._check_ready()
        return sum(1 for s in self._slots if s.ready and s.job_id is None)

    def _check_ready(self) -> None:
        pending = [s.ready_ref for s in self._slots if not s.ready and s.ready_ref is not None]
        if not pending:
            return
        done, _ = self.ray.wait(pending, num_returns=len(pending), timeout=0)
        for slot in self._slots:
            if slot.ready_ref is not None and slot.ready_ref in done:
                try:
                    slot.pid = self.ray.get(slot.ready_ref)
                    slot.ready = True
                except Exception as exc:  # noqa: BLE001
                    log.error("a Ray worker failed to start: %s; retrying", exc)
                    self._spawn(slot)
                    continue
                slot.ready_ref = None

    def start(self, job_id: str, kind: str, request: dict[str, Any]) -> str:
        for slot in self._slots:
            if slot.ready and slot.job_id is None:
                slot.job_id, slot.kill_at, slot.last_seq = job_id, None, 0
                slot.run_ref = slot.actor.run.remote(job_id, kind, request)
                return f"ray actor pid {slot.pid}"
        raise RuntimeError("no free Ray worker")

    def cancel(self, job_id: str) -> None:
        for slot in self._slots:
            if slot.job_id == job_id and slot.kill_at is None:
                slot.actor.cancel.remote()
                slot.kill_at = time.monotonic() + self.settings.cancel_grace_s

    def poll(self, timeout: float) -> list[ExecEvent]:
        events: list[ExecEvent] = []
        self._check_ready()
        runs = [s.run_ref for s in self._slots if s.run_ref is not None]
        done: list[Any] = []
        if runs:
            done, _ = self.ray.wait(runs, num_returns=len(runs), timeout=timeout)
        else:
            time.sleep(timeout)
        for slot in self._slots:
            if slot.job_id is None:
                continue
            job_id = slot.job_id
            if slot.run_ref in done:
                self._collect_progress(slot, events, final=True)
                try:
                    tag, value = self.ray.get(slot.run_ref)
                except Exception as exc:  # noqa: BLE001 - actor died (crash, OOM, node loss)
                    events.append(ExecEvent(job_id, "error", error={
                        "code": "WORKER_CRASHED", "message": f"Ray worker died while running the job: {type(exc).__name__}: {exc}"}))
                    self._spawn(slot)
                    continue
                slot.job_id, slot.run_ref, slot.kill_at = None, None, None
                if tag == "done":
                    events.append(ExecEvent(job_id, "done", result=value))
                elif tag == "canceled":
                    events.append(ExecEvent(job_id, "canceled", message="stopped after a cancel"))
                else:
                    events.append(ExecEvent(job_id, "error", error=value))
                continue
            if slot.kill_at is not None and time.monotonic() >= slot.kill_at:
                self.ray.kill(slot.actor, no_restart=True)
                events.append(ExecEvent(job_id, "canceled", message="Ray worker killed: it did not stop within the grace period"))
                self._spawn(slot)
                continue
            self._collect_progress(slot, events)
        return events

    def _collect_progress(self, slot: _Slot, events: list[ExecEvent], final: bool = False) -> None:
        if slot.progress_ref is None:
            if not final:
                slot.progress_ref = slot.actor.progress.remote()
            return
        ready, _ = self.ray.wait([slot.progress_ref], timeout=0)
        if not ready:
            return
        try:
            latest = self.ray.get(slot.progress_ref)
        except Exception:  # noqa: BLE001
            latest = None
        slot.progress_ref = None if final else slot.actor.progress.remote()
        if latest is not None and latest[2] > slot.last_seq and slot.job_id is not None:
            slot.last_seq = latest[2]
            events.append(ExecEvent(slot.job_id, "progress", fraction=latest[0], message=latest[1]))

    def close(self) -> None:
        for slot in self._slots:
            try:
                self.ray.kill(slot.actor, no_restart=True)
            except Exception:  # noqa: BLE001
                pass
