"""Run jobs on a Ray cluster through the same executor interface.

One threaded Ray actor per slot loads the robot model once and runs one job at
a time; a second actor thread answers ``cancel()`` and ``progress()`` while the
job runs, so cancel and progress work exactly as with local processes. An actor
that has not stopped ``cancel_grace_s`` after a cancel is killed
(``ray.kill``) and replaced; an actor that dies fails its job with the reason.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
import time
from dataclasses import dataclass
from typing import Any

from ..settings import ServiceSettings
from .base import ExecEvent, crashed_event, outcome_event

log = logging.getLogger("regrasp.ray")


class _ActorContext:
    """The ``ctx`` of a job in a Ray actor: progress is kept for the executor to fetch, cancel is per job id."""

    def __init__(self, actor: "_JobActorImpl", job_id: str) -> None:
        self._actor = actor
        self._job_id = job_id

    def progress(self, fraction: float, message: str) -> None:
        with self._actor.lock:
            self._actor.seq += 1
            self._actor.latest = (min(1.0, max(0.0, float(fraction))), str(message)[:500], self._actor.seq)

    def cancelled(self) -> bool:
        return self._job_id in self._actor.canceled

    @property
    def seed_map(self):  # type: ignore[no-untyped-def]
        """On a cluster (``ray_address``), a survey's seeds run as tasks across its nodes
        (service.executors.ray_seeds); a local instance's CPUs are the actors' own, so they run here."""
        if not self._actor.fan_out:
            return None
        from .ray_seeds import RaySeeds

        return RaySeeds()


#: How often a local instance's actor looks whether its server is still alive.
SERVER_CHECK_S = 0.1


def _alive(pid: int) -> bool:
    """The process exists and is not a zombie (a killed server stays one until its parent reaps it)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        try:
            os.kill(pid, 0)
            return True
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
    except IndexError:
        return True


def _exit_with(pid: int) -> None:
    """Exit at once when the server ``pid`` is gone (a kill -9 of the server must not leave planners running)."""
    while _alive(pid):
        time.sleep(SERVER_CHECK_S)
    os._exit(3)


class _JobActorImpl:
    """Body of the Ray actor (wrapped with ``ray.remote`` lazily, so importing this module needs no Ray).

    Cancels name the job, so a cancel that reaches the actor before its job starts still counts.
    """

    def __init__(self, handlers: dict[str, str], robot: str | None, nice: int = 0, fan_out: bool = False,
                 server_pid: int | None = None) -> None:
        from ..jobs.worker_process import JobHandlers, lower_priority

        lower_priority(nice)
        self.fan_out = fan_out
        if server_pid is not None:  # a local instance: the actor ends with its server (Ray takes ~2 s to notice)
            threading.Thread(target=_exit_with, args=(server_pid,), daemon=True, name="server-watch").start()
        self.jobs = JobHandlers(handlers, robot)
        self.canceled: set[str] = set()
        self.lock = threading.Lock()
        self.latest: tuple[float, str, int] | None = None
        self.seq = 0

    def ready(self) -> int:
        return os.getpid()

    def run(self, job_id: str, kind: str, request: dict[str, Any]) -> tuple[str, Any]:
        with self.lock:
            self.latest = None
        try:
            return self.jobs.run(kind, request, _ActorContext(self, job_id))
        finally:
            self.canceled.discard(job_id)

    def cancel(self, job_id: str) -> None:
        self.canceled.add(job_id)

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


def _first_line(exc: BaseException) -> str:
    """Ray's errors run to many lines (tracebacks, hints); a job's error keeps the first that says something."""
    for line in str(exc).splitlines():
        if line.strip():
            return line.strip()[:300]
    return type(exc).__name__


class RayExecutor:
    """``settings.workers`` Ray actors, on a local Ray instance or the cluster at ``settings.ray_address``."""

    name = "ray"

    def __init__(self, settings: ServiceSettings) -> None:
        import ray

        self.ray = ray
        self.settings = settings
        slots = max(settings.workers, 1)
        actor_cpus = 1.0
        # ray.init installs its own SIGTERM handler (a SystemExit raised wherever the main thread is);
        # the server's handler, a graceful stop, is put back.
        sigterm = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
        if not ray.is_initialized():
            if settings.ray_address:
                ray.init(address=settings.ray_address, ignore_reinit_error=True, log_to_driver=False)
            else:
                # A local instance offers ray_num_cpus (default one per worker), shared by the actors, and
                # no dashboard: its footprint is the workers' own.
                cpus = settings.ray_num_cpus or float(slots)
                actor_cpus = min(1.0, cpus / slots)
                ray.init(ignore_reinit_error=True, include_dashboard=False, log_to_driver=False,
                         num_cpus=math.ceil(cpus), object_store_memory=settings.ray_object_store_bytes)
        if sigterm is not None:
            signal.signal(signal.SIGTERM, sigterm)
        # max_restarts=0: an actor that dies fails its job (WORKER_CRASHED), as a local worker process does.
        self._actor_cls = ray.remote(num_cpus=actor_cpus, max_concurrency=3, max_restarts=0)(_JobActorImpl)
        self._slots = [_Slot() for _ in range(settings.workers)]
        for slot in self._slots:
            self._spawn(slot)

    def _spawn(self, slot: _Slot) -> None:
        robot = self.settings.robot if self.settings.preload_robot else None
        slot.actor = self._actor_cls.remote(dict(self.settings.handlers), robot, self.settings.worker_nice,
                                            bool(self.settings.ray_address),
                                            None if self.settings.ray_address else os.getpid())
        slot.ready_ref = slot.actor.ready.remote()
        slot.ready, slot.job_id, slot.run_ref, slot.progress_ref, slot.kill_at = False, None, None, None, None
        slot.last_seq, slot.pid = 0, None

    def _replace(self, slot: _Slot) -> None:
        """Kill the slot's actor (``ray.kill`` does not wait for it) and start a fresh one."""
        try:
            self.ray.kill(slot.actor, no_restart=True)
        except Exception as exc:  # noqa: BLE001 - an actor that is already gone cannot be killed again
            log.debug("ray.kill of a dead actor: %s", exc)
        self._spawn(slot)

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
                    log.error("a Ray worker failed to start: %s; retrying", _first_line(exc))
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
                slot.actor.cancel.remote(job_id)
                slot.kill_at = time.monotonic() + self.settings.cancel_grace_s

    def poll(self, timeout: float) -> list[ExecEvent]:
        events: list[ExecEvent] = []
        self._check_ready()
        runs = [s.run_ref for s in self._slots if s.run_ref is not None]
        # Wake for the first finished job, or at the first kill deadline, whichever comes first.
        deadlines = [s.kill_at for s in self._slots if s.kill_at is not None]
        if deadlines:
            timeout = max(0.0, min(timeout, min(deadlines) - time.monotonic()))
        done: list[Any] = []
        if runs:
            done, _ = self.ray.wait(runs, num_returns=1, timeout=timeout)
            if done:  # collect every other job that has finished too
                done, _ = self.ray.wait(runs, num_returns=len(runs), timeout=0)
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
                    events.append(crashed_event(job_id, f"Ray worker (actor pid {slot.pid}) died while running the "
                                                        f"job: {_first_line(exc)}"))
                    self._replace(slot)
                    continue
                slot.job_id, slot.run_ref, slot.kill_at = None, None, None
                events.append(outcome_event(job_id, tag, value))
                continue
            if slot.kill_at is not None and time.monotonic() >= slot.kill_at:
                self._replace(slot)
                events.append(ExecEvent(job_id, "canceled", message="Ray worker killed: it did not stop within the grace period"))
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
        except Exception:  # noqa: BLE001 - the actor died; its run reference reports why
            latest = None
        slot.progress_ref = None if final else slot.actor.progress.remote()
        if latest is not None and latest[2] > slot.last_seq and slot.job_id is not None:
            slot.last_seq = latest[2]
            events.append(ExecEvent(slot.job_id, "progress", fraction=latest[0], message=latest[1]))

    def close(self) -> None:
        for slot in self._slots:
            try:
                self.ray.kill(slot.actor, no_restart=True)
            except Exception:  # noqa: BLE001 - closing: an actor already gone is fine
                pass
