"""Dispatch and execution of approved plans through the robot bridge.

A dispatch moves the job ``approved -> dispatching`` (compare-and-set, so two
operators cannot dispatch twice), then a thread runs ``bridge.execute``: the
bridge's safety gate rechecks the plan, segments go to the controller, and the
bridge's events are stored as job events (so they reach the SSE stream and the
audit file). The first event past the gate moves the job to ``executing``; the
outcome ends it ``succeeded``, ``rejected`` (gate veto) or ``aborted``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from datetime import datetime, timedelta
from typing import Any

from ..errors import RegraspServiceError
from ..jobs.owners import LiveOwners, make_owner_id
from ..settings import ServiceSettings
from ..store.repo import JobStore
from .balance import start_balance_watch
from .bridge import Bridge

log = logging.getLogger("regrasp.execution")

#: How often running executions look for a stop requested through another API replica, s.
STOP_POLL_S = 0.2
#: How long the end of an execution waits for its queued events to be stored, s.
EVENT_DRAIN_TIMEOUT_S = 30.0
#: Bridge events that mean the robot is being driven (robot_bridge.dispatcher names them so).
EXECUTING_EVENTS = frozenset({"executing", "segment", "robot_state"})
#: Rate of the balance samples an execution records in its events (and so its audit), Hz.
BALANCE_EVENT_HZ = 10.0
#: Exceptions of the bridge raised before anything was sent: the job goes back to approved.
NOT_STARTED_ERRORS = frozenset({"ControllerUnavailableError", "BusyError", "NoSigningKeyError"})



#: What a start-state veto adds to the job's error: the way out.
START_STATE_WAY_OUT = ("; the way out: plan the way back first (a recover job, POST /v1/jobs {\"kind\": \"recover\", "
                       "\"request\": {\"robot\": ...}}, or \"Plan the way back\" in the console), have it approved and "
                       "dispatch it, then plan this task again from the stance posture")


def _check_of(verdict: Any) -> str | None:
    """The check a gate verdict names (a verdict object or its dict), or None."""
    if verdict is None:
        return None
    check = verdict.get("check") if isinstance(verdict, dict) else getattr(verdict, "check", None)
    return str(check) if check is not None else None


class RobotBusy(RegraspServiceError):
    """Another job of the robot is dispatching or executing (one dispatch at a time): HTTP 409 naming it."""

    def __init__(self, running_job_id: str) -> None:
        super().__init__(f"job {running_job_id} is executing on the robot; one execution at a time")
        self.running_job_id = running_job_id


class Executions:
    """Runs dispatched jobs on the bridge, one thread each, and stops them on request."""

    def __init__(self, store: JobStore, bridge: Bridge, settings: ServiceSettings,
                 owners: LiveOwners | None = None) -> None:
        self.store = store
        self.bridge = bridge
        self.settings = settings
        self.owner = make_owner_id()
        self.owners = owners or LiveOwners()
        self.owners.add(self.owner)
        self._stops: dict[str, threading.Event] = {}
        self._threads: dict[str, threading.Thread] = {}
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._renewer = threading.Thread(target=self._renew_loop, name="regrasp-exec-lease", daemon=True)
        self._renewer.start()
        # A controller lost during a job and heard from again gets the stop again; the job's record says so.
        if hasattr(bridge, "on_controller_return"):
            bridge.on_controller_return = self._record_stop_resent
        # The physics plant's balance stream, when the bridge is a real one: the console's CoP trace, the audit's.
        self.balance = start_balance_watch() if hasattr(bridge, "on_controller_return") else None

    def _record_stop_resent(self, job_id: str, data: dict[str, Any]) -> None:
        """Store the re-sent stop as a bridge event of the job (its audit file records it)."""
        try:
            self.store.add_event(job_id, "bridge", message="stop_resent",
                                 data={"event": "stop_resent", "payload": _jsonable(data)})
        except Exception:  # noqa: BLE001 - called from a zenoh thread: never raise into it
            log.exception("storing the re-sent stop of job %s failed", job_id)

    def begin(self, job: dict[str, Any], plan: str | bytes, by: str, physics: dict[str, Any] | None = None) -> bool:
        """Move the job to dispatching and start executing it; False if it was no longer approved.

        The move is decided in the job store, atomically with every other dispatch of the robot: raises
        :class:`RobotBusy` naming the running job when another one is dispatching or executing.
        ``plan`` is the stored plan's canonical JSON text, whose SHA-256 is the approved hash. ``physics``: its
        physics dry run's report, for the bridge's gate when the safety policy requires one."""
        job_id = job["id"]
        lease = datetime.now(job["approval_expires_at"].tzinfo) + timedelta(seconds=self.settings.lease_s)
        ok, running = self.store.begin_dispatch(job_id, message=f"dispatched by {by}",
                                                data={"by": by, "plan_sha256": job["approved_sha256"]},
                                                owner=self.owner, lease_expires_at=lease)
        if running is not None:
            raise RobotBusy(running)
        if not ok:
            return False
        stop = threading.Event()
        thread = threading.Thread(target=self._run, args=(job, plan, stop, physics), name=f"exec-{job_id[:8]}", daemon=True)
        with self._lock:
            self._stops[job_id] = stop
            self._threads[job_id] = thread
        thread.start()
        return True

    def _run(self, job: dict[str, Any], plan: str | bytes, stop: threading.Event,
             physics: dict[str, Any] | None = None) -> None:
        job_id = job["id"]

        # The control path never waits on the database: events are queued here and written by another thread.
        pending: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        writer = threading.Thread(target=self._write_events, args=(job_id, pending), name=f"exec-events-{job_id[:8]}",
                                  daemon=True)
        writer.start()

        def on_event(name: str, payload: dict[str, Any]) -> None:
            pending.put((str(name), dict(payload) if isinstance(payload, dict) else payload))

        last_balance = [-float("inf")]

        def on_balance(sample: dict[str, Any]) -> None:  # into the job's events (and its audit) at BALANCE_EVENT_HZ
            stamp = float(sample.get("stamp") or 0.0)
            if stamp - last_balance[0] >= 1.0 / BALANCE_EVENT_HZ:
                last_balance[0] = stamp
                on_event("balance", sample)

        unlisten = self.balance.listen(on_balance) if self.balance is not None else (lambda: None)

        try:
            outcome = self.bridge.execute(
                plan, job_id=job_id, approved_sha256=job["approved_sha256"],
                approval_expires_at=job["approval_expires_at"],
                # None: the plan's own threshold, never below the safety policy's floor (the bridge's gate holds it)
                threshold_m=None,
                on_event=on_event, stop_event=stop,
                **({"recovery": True} if job.get("kind") == "recover" else {}),
                **({"physics": physics} if physics is not None else {}),
            )
            status, reason, verdict = outcome.status, outcome.reason, outcome.verdict
            details = outcome.details
        except Exception as exc:  # noqa: BLE001 - a bridge fault aborts the execution
            if type(exc).__name__ in NOT_STARTED_ERRORS:
                unlisten()
                pending.put(None)
                writer.join(EVENT_DRAIN_TIMEOUT_S)
                self.store.transition(job_id, ["dispatching"], "approved", expect_owner=self.owner, owner=None,
                                      lease_expires_at=None, message=f"dispatch did not start: {exc}",
                                      data={"reason": str(exc)})
                self._forget(job_id)
                return
            log.exception("execution of job %s failed", job_id)
            status, reason, verdict, details = "aborted", f"bridge error: {type(exc).__name__}: {exc}", None, {}
        unlisten()
        pending.put(None)
        writer.join(EVENT_DRAIN_TIMEOUT_S)
        if stop.is_set() and status == "aborted" and not reason:
            reason = "stopped by an operator"
        error = None
        if status == "rejected":
            if _check_of(verdict) == "start_state":
                reason = (reason or "the robot is not where the plan starts") + START_STATE_WAY_OUT
            error = {"code": "GATE_VETO", "message": reason or "the safety gate vetoed the plan"}
        elif status == "aborted":
            error = {"code": "ABORTED", "message": reason or "execution aborted"}
        message = {"succeeded": "executed", "rejected": f"vetoed by the safety gate: {reason}",
                   "aborted": f"aborted: {reason}"}.get(status, status)
        self.store.transition(job_id, ["dispatching", "executing"], status, message=message, error=error,
                              data={"execution": True, "reason": reason, "verdict": _jsonable(verdict),
                                    "details": _jsonable(details)})
        self._forget(job_id)

    def _write_events(self, job_id: str, pending: "queue.Queue[tuple[str, Any] | None]") -> None:
        """Store the bridge's events in order; the first one showing motion moves the job to executing."""
        executing = False
        while True:
            item = pending.get()
            if item is None:
                return
            name, payload = item
            try:
                self.store.add_event(job_id, "bridge", message=name, data={"event": name, "payload": _jsonable(payload)})
                if not executing and name in EXECUTING_EVENTS:
                    executing = True
                    self.store.transition(job_id, ["dispatching"], "executing", message="executing on the robot",
                                          expect_owner=self.owner)
            except Exception:  # noqa: BLE001 - a lost event must not stop the others
                log.exception("storing bridge event %s of job %s failed", name, job_id)

    def _forget(self, job_id: str) -> None:
        with self._lock:
            self._stops.pop(job_id, None)
            self._threads.pop(job_id, None)

    def busy_with(self) -> str | None:
        """The job being executed now, if any (one execution at a time per service)."""
        with self._lock:
            return next(iter(self._threads), None)

    def stop(self, job_id: str, by: str) -> bool:
        """Ask the bridge to stop now; the job ends aborted when execute() returns."""
        self.store.update_fields(job_id, stop_requested=True)
        self.store.add_event(job_id, "note", message=f"stop requested by {by}", data={"by": by})
        with self._lock:
            stop = self._stops.get(job_id)
        if stop is not None:
            stop.set()
        try:
            self.bridge.stop(job_id)
        except Exception:  # noqa: BLE001
            log.exception("bridge.stop(%s) failed", job_id)
        return stop is not None

    def _renew_loop(self) -> None:
        """Renew the leases of running executions and honour stops requested through another replica."""
        last_renew = 0.0
        while not self._closing.wait(STOP_POLL_S):
            with self._lock:
                running = list(self._threads)
            if not running:
                continue
            try:
                now = time.monotonic()
                if now - last_renew >= self.settings.lease_s / 3:
                    last_renew = now
                    self.store.renew(self.owner, running, self.settings.lease_s)
                for job_id, row in self.store.flags(running).items():
                    if row["stop_requested"]:
                        with self._lock:
                            stop = self._stops.get(job_id)
                        if stop is not None and not stop.is_set():
                            stop.set()
                            self.bridge.stop(job_id)
            except Exception:  # noqa: BLE001
                log.exception("execution lease renewal failed")

    def close(self) -> None:
        self._closing.set()
        with self._lock:
            stops = list(self._stops.items())
        for job_id, stop in stops:
            stop.set()
            try:
                self.bridge.stop(job_id)
            except Exception:  # noqa: BLE001
                pass
        for thread in list(self._threads.values()):
            thread.join(5)
        if self.balance is not None:
            self.balance.close()
        self.owners.discard(self.owner)


def _jsonable(value: Any) -> Any:
    """Bridge payloads may hold numpy values or dataclasses: make them JSON."""
    import json

    try:
        json.dumps(value, allow_nan=False)
        return value
    except (TypeError, ValueError):
        pass
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return _jsonable(value.tolist())
    if isinstance(value, float):
        return repr(value)
    if hasattr(value, "__dict__"):
        return _jsonable({k: v for k, v in vars(value).items() if not k.startswith("_")})
    return repr(value)
