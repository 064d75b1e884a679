"""The dispatcher in a process of its own, driven from the service through pipes.

Why: the dispatcher's heartbeat (the controller's dead-man) and its watchdog on
the controller's heartbeat are Python threads, and a Python thread runs only while
it holds its process's interpreter lock. In the service's process the API, the job
store and the event writers hold it too; with both cores busy a thread holding it
is descheduled while it holds it, and the bridge's threads wait: the dispatcher's
heartbeat went out 250 ms late and the controller stopped a healthy execution (see
``benchmarks/bench_bridge_safety.py``). In this process nothing but the bridge
runs Python, at the bridge's thread priority.

:class:`DispatcherProcess` offers the :class:`~robot_bridge.dispatcher.Dispatcher`
methods the service uses (``execute``, ``stop``, ``controller_problem``,
``controller_alive``, ``measured_state``, ``close``, ``on_controller_return``). The
child sends a status snapshot (controller problem, measured state) every
``STATUS_PERIOD_S``, each execution's events as they happen and its result; the
parent sends commands. If the child dies, a running execution ends ``aborted``
and the controller's own dead-man stops the robot; if the parent dies, the child
exits.
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing as mp
import os
import threading
import time
from datetime import datetime
from typing import Any, Callable

from schemas.bridge import GateVerdict, JointState
from schemas.policy import SafetyPolicy, default_policy

from .dispatcher import (
    BusyError,
    ControllerUnavailableError,
    Dispatcher,
    DispatchSettings,
    ExecutionResult,
    NoSigningKeyError,
    wait_for_controller,
)
from .settings import BridgeSettings

log = logging.getLogger("regrasp.bridge")

#: How often the child sends its status snapshot, s.
STATUS_PERIOD_S = 0.02
#: A snapshot older than this means the bridge process is not answering, s.
STATUS_STALE_S = 1.0
#: How long the child may take to start (imports, zenoh session), s.
START_TIMEOUT_S = 60.0
_ERRORS: dict[str, type[Exception]] = {e.__name__: e for e in (BusyError, ControllerUnavailableError, NoSigningKeyError)}


class DispatcherProcess:
    """A :class:`Dispatcher` running in a child process (spawned), with the same calls."""

    def __init__(self, settings: BridgeSettings | None = None, dispatch: DispatchSettings | None = None,
                 policy: SafetyPolicy | None = None):
        self.settings = settings or BridgeSettings()
        self.dispatch = dispatch or DispatchSettings()
        #: The site's safety policy the child's gate enforces.
        self.policy = policy or default_policy()
        self.on_controller_return: Callable[[str, dict[str, Any]], None] | None = None
        ctx = mp.get_context("spawn")
        self._cmd, cmd_child = ctx.Pipe()
        self._out, out_child = ctx.Pipe(duplex=False)
        self._send_lock = threading.Lock()
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._calls: dict[int, dict[str, Any]] = {}
        self._status: dict[str, Any] = {"problem": "the bridge process is starting", "measured": None}
        self._status_at = time.monotonic()
        self._dead: str | None = None
        self._proc = ctx.Process(target=_child_main, name="regrasp-bridge", daemon=True,
                                 args=(self.settings.model_dump(mode="json"), self.dispatch.model_dump(mode="json"),
                                       cmd_child, out_child, os.getpid(),
                                       (self.policy.document(), self.policy.source)))
        self._proc.start()
        cmd_child.close()
        out_child.close()
        if not self._out.poll(START_TIMEOUT_S):
            self._proc.kill()
            raise RuntimeError("the bridge process did not start in time")
        kind, info = self._out.recv()
        if kind == "failed":
            self._proc.join(5)
            raise RuntimeError(f"the bridge process failed to start: {info}")
        #: Truthy when the child signs commands (it loaded the signing key), as Dispatcher.signer.
        self.signer = info.get("signing") or None
        self.signing_problem: str | None = info.get("signing_problem")
        self._reader = threading.Thread(target=self._read, name="regrasp-bridge-reader", daemon=True)
        self._reader.start()

    # ------------------------------------------------------------------ parent side
    def _send(self, msg: tuple) -> None:
        with self._send_lock:
            self._cmd.send(msg)

    def _read(self) -> None:
        while True:
            try:
                msg = self._out.recv()
            except (EOFError, OSError):
                break
            kind = msg[0]
            if kind == "status":
                with self._lock:
                    self._status, self._status_at = msg[1], time.monotonic()
            elif kind == "event":
                call = self._calls.get(msg[1])
                if call is not None:
                    try:
                        call["on_event"](msg[2], msg[3])
                    except Exception:  # noqa: BLE001 - a failing recorder must not stop the reader
                        log.exception("bridge event callback failed")
            elif kind in ("result", "error"):
                call = self._calls.get(msg[1])
                if call is not None:
                    call["outcome"] = msg
                    call["done"].set()
            elif kind == "returned":
                callback = self.on_controller_return
                if callback is not None:
                    try:
                        callback(msg[1], msg[2])
                    except Exception:  # noqa: BLE001
                        log.exception("on_controller_return failed")
        self._dead = f"the bridge process ended (exit code {self._proc.exitcode})"
        for call in list(self._calls.values()):
            call["done"].set()

    def controller_problem(self) -> str | None:
        if self._dead:
            return self._dead
        with self._lock:
            status, at = self._status, self._status_at
        if time.monotonic() - at > STATUS_STALE_S:
            return f"the bridge process has not reported for {time.monotonic() - at:.1f} s"
        return status.get("problem")

    def controller_alive(self) -> bool:
        return self.controller_problem() is None

    def measured_state(self) -> JointState | None:
        with self._lock:
            measured, at = self._status.get("measured"), self._status_at
        if measured is None or self._dead or time.monotonic() - at > STATUS_STALE_S:
            return None
        return JointState.model_validate(measured)

    def wait_for_controller(self, timeout_s: float) -> bool:
        return wait_for_controller(self, timeout_s)

    def stop(self, job_id: str | None = None, reason: str = "stop requested by operator") -> None:
        if not self._dead:
            self._send(("stop", job_id, reason))

    def execute(self, plan: dict[str, Any] | str | bytes, *, job_id: str, approved_sha256: str,
                approval_expires_at: datetime, threshold_m: float | None = None,
                on_event: Callable[[str, dict[str, Any]], None] | None = None,
                stop_event: threading.Event | None = None, recovery: bool = False,
                physics: dict[str, Any] | None = None) -> ExecutionResult:
        if self._dead:
            raise ControllerUnavailableError(self._dead)
        cid = next(self._ids)
        call = {"on_event": on_event or (lambda k, d: None), "done": threading.Event(), "outcome": None}
        self._calls[cid] = call
        try:
            self._send(("execute", cid, plan, {"job_id": job_id, "approved_sha256": approved_sha256,
                                               "approval_expires_at": approval_expires_at, "threshold_m": threshold_m,
                                               "recovery": recovery, "physics": physics}))
            stop_sent = False
            while not call["done"].wait(0.005 if stop_event is not None else 0.5):
                if stop_event is not None and stop_event.is_set() and not stop_sent:
                    self._send(("stop_event", cid))
                    stop_sent = True
            outcome = call["outcome"]
        finally:
            self._calls.pop(cid, None)
        if outcome is None:
            return ExecutionResult("aborted", self._dead or "the bridge process ended during the execution")
        if outcome[0] == "error":
            _, _, name, message = outcome
            raise _ERRORS.get(name, RuntimeError)(message)
        res = outcome[2]
        verdict = GateVerdict.model_validate(res["verdict"]) if res.get("verdict") else None
        return ExecutionResult(res["status"], res["reason"], verdict, res.get("last_index"), res.get("segments_sent", 0),
                               res.get("duration_s", 0.0), res.get("details") or {})

    def close(self) -> None:
        if self._proc.is_alive():
            try:
                self._send(("close",))
            except (OSError, BrokenPipeError):
                pass
            self._proc.join(5)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(5)


# ---------------------------------------------------------------------- child side
def _child_main(settings_doc: dict, dispatch_doc: dict, cmd: Any, out: Any, parent_pid: int,
                policy: tuple[dict, str] | None = None) -> None:
    """The bridge process: one Dispatcher, its status every STATUS_PERIOD_S, commands from the parent."""
    from .process_tuning import (
        freeze_startup_objects,
        raise_thread_priority,
        shorten_switch_interval,
        use_realtime_scheduling,
    )

    send_lock = threading.Lock()

    def send(msg: tuple) -> None:
        with send_lock:
            out.send(msg)

    # Raised before zenoh starts its threads, which inherit it; the whole process carries only bridge traffic.
    raise_thread_priority(settings_doc.get("thread_nice"))
    use_realtime_scheduling(settings_doc.get("realtime_priority"))
    shorten_switch_interval()
    try:
        settings = BridgeSettings(**settings_doc)
        safety = SafetyPolicy.model_validate(policy[0]).with_source(policy[1]) if policy is not None else None
        disp = Dispatcher(settings, DispatchSettings(**dispatch_doc), policy=safety)
    except Exception as exc:  # noqa: BLE001 - the parent reports it
        send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    problem = None if disp.signer is not None or settings.signing_key is None else "the signing key was not loaded"
    send(("ready", {"signing": disp.signer is not None, "signing_problem": problem}))
    disp.on_controller_return = lambda job_id, data: send(("returned", job_id, data))
    freeze_startup_objects()
    closing = threading.Event()
    stops: dict[int, threading.Event] = {}

    def status_loop() -> None:
        while not closing.wait(STATUS_PERIOD_S):
            if os.getppid() != parent_pid:
                os._exit(0)  # the service is gone; the controller's dead-man stops the robot
            js = disp.measured_state()
            try:
                send(("status", {"problem": disp.controller_problem(),
                                 "measured": js.model_dump(mode="json") if js is not None else None}))
            except (OSError, BrokenPipeError):
                os._exit(0)

    def run(cid: int, plan: Any, kwargs: dict) -> None:
        try:
            res = disp.execute(plan, on_event=lambda kind, data: send(("event", cid, kind, data)),
                               stop_event=stops[cid], **kwargs)
            send(("result", cid, res.to_dict()))
        except Exception as exc:  # noqa: BLE001 - raised again in the parent by name
            send(("error", cid, type(exc).__name__, str(exc)))
        finally:
            stops.pop(cid, None)

    threading.Thread(target=status_loop, name="bridge-status", daemon=True).start()
    try:
        while True:
            try:
                msg = cmd.recv()
            except (EOFError, OSError):
                break
            if msg[0] == "execute":
                _, cid, plan, kwargs = msg
                stops[cid] = threading.Event()
                threading.Thread(target=run, args=(cid, plan, kwargs), name=f"bridge-exec-{cid}", daemon=True).start()
            elif msg[0] == "stop_event":
                ev = stops.get(msg[1])
                if ev is not None:
                    ev.set()
            elif msg[0] == "stop":
                disp.stop(msg[1], msg[2])
            elif msg[0] == "close":
                break
    finally:
        closing.set()
        for ev in list(stops.values()):
            ev.set()
        disp.close()
