"""The runner: claims queued jobs, feeds them to an executor, and records what happens.

One runner per ``regrasp serve`` (a background thread) or ``regrasp worker``
process. It is the only writer of a claimed job until the job leaves
``planning``; its lease on the job is renewed while it runs, so another runner
recovers the job if this one dies (SIGKILL included).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

from schemas.policy import SafetyPolicy

from ..executors.base import ExecEvent, Executor
from ..settings import ServiceSettings
from ..store.health import StorageHealth, storage_trouble
from ..store.repo import JobStore
from .owners import LiveOwners, make_owner_id
from .provenance import code_version, library_versions, robot_sha256

log = logging.getLogger("regrasp.runner")

#: Housekeeping (recovery of stale jobs, approval expiry) period.
HOUSEKEEPING_S = 0.5
#: Cancel flags of running jobs are read this often (cancel takes effect within ~this + the grace period).
FLAG_POLL_S = 0.1


@dataclass
class _Running:
    job_id: str
    kind: str
    started: float
    deadline: float
    last_progress_store: float = 0.0
    pending_progress: tuple[float, str] | None = None
    cancel_reason: str | None = None  # "canceled" | "timeout"


class Runner:
    """Claims jobs for one executor and moves them through planning to their outcome."""

    def __init__(self, store: JobStore, executor: Executor, settings: ServiceSettings,
                 *, owner: str | None = None, owners: LiveOwners | None = None,
                 policy: SafetyPolicy | None = None, storage: StorageHealth | None = None) -> None:
        self.store = store
        #: The data directory's health: while it is sick, running jobs fail with its reason and none is claimed.
        self.storage = storage
        #: Jobs whose failure could not be written yet (the disk was full), retried every step: job id -> reason.
        self._unrecorded: dict[str, tuple[_Running, str]] = {}
        self.executor = executor
        self.settings = settings
        #: The site's safety policy: a plan job planned below its floor ends as a comparison.
        self.policy = policy or settings.safety_policy()
        self.owner = owner or make_owner_id()
        #: The owners alive in this process (shared with the service's executions).
        self.owners = owners or LiveOwners()
        self.owners.add(self.owner)
        self._running: dict[str, _Running] = {}
        self._stop = threading.Event()
        self._flags_due = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_housekeeping = 0.0
        self._last_flags = 0.0
        self._last_renew = 0.0

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._thread = threading.Thread(target=self.run_forever, name="regrasp-runner", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self.owners.discard(self.owner)

    def nudge(self) -> None:
        """Read the cancel flags at the next step instead of up to ``FLAG_POLL_S`` later (thread-safe).

        The API calls this after storing a cancel request, so an embedded runner acts on it at
        once; a runner in another process (``regrasp worker``) still finds it by polling.
        """
        self._flags_due.set()

    def run_forever(self) -> None:
        while not self._stop.is_set():
            try:
                self.step()
            except Exception as exc:  # noqa: BLE001 - a DB hiccup must not kill the runner
                reason = self.storage.note_failure(exc, "a job store write") if self.storage is not None else None
                if reason is None and storage_trouble(exc) is None:
                    log.exception("runner step failed; retrying")
                else:
                    log.error("runner step failed: %s; retrying", reason or storage_trouble(exc))
                time.sleep(0.5)

    # ----------------------------------------------------------------- step
    def step(self) -> None:
        for event in self.executor.poll(self.settings.poll_interval_s):
            self._handle(event)
        sick = self.storage.check() if self.storage is not None else None
        if sick is not None or self._unrecorded:
            self._fail_for_storage(sick)
            if sick is not None:
                return  # no progress writes, no claims while the data cannot be kept
        now = time.monotonic()
        self._flush_progress(now)
        if self._flags_due.is_set() or now - self._last_flags >= FLAG_POLL_S:
            self._flags_due.clear()
            self._last_flags = now
            self._check_flags_and_deadlines(now)
        if now - self._last_renew >= self.settings.lease_s / 3:
            self._last_renew = now
            self.store.renew(self.owner, list(self._running), self.settings.lease_s)
        if now - self._last_housekeeping >= HOUSEKEEPING_S:
            self._last_housekeeping = now
            for job_id, outcome in self.store.recover(self.owners.is_dead, self.settings.max_attempts):
                log.warning("recovered job %s -> %s", job_id, outcome)
            self.store.expire_approvals()
        self._claim()

    def _claim(self) -> None:
        free = self.executor.free_slots()
        if free <= 0:
            return
        extra = {"code_version": code_version(), "library_versions": library_versions()}
        for job in self.store.claim(self.owner, free, self.settings.lease_s, extra):
            self._launch(job)

    def _launch(self, job: dict[str, Any]) -> None:
        job_id = job["id"]
        now = time.monotonic()
        self._running[job_id] = _Running(job_id, job["kind"], now, now + self._timeout_s(job))
        if job["cancel_requested"]:  # canceled between the claim and the start
            self._running[job_id].cancel_reason = "canceled"
            self._finish_canceled(job_id, "canceled before it started")
            return
        try:
            where = self.executor.start(job_id, job["kind"], job["request"])
        except Exception as exc:  # noqa: BLE001
            run = self._running.pop(job_id)
            self._finish(run, "failed", f"could not start: {exc}",
                         error={"code": "ERROR", "message": f"could not start the job: {exc}"})
            return
        self.store.add_event(job_id, "note", message=f"running on {where}", data={"worker": where, "runner": self.owner})

    def _timeout_s(self, job: dict[str, Any]) -> float:
        limit = self.settings.job_timeout_s
        planner_limit = (job.get("request") or {}).get("time_limit_s")
        if planner_limit:
            limit = min(limit, float(planner_limit) + self.settings.timeout_margin_s)
        return limit

    # --------------------------------------------------------------- events
    def _handle(self, ev: ExecEvent) -> None:
        run = self._running.get(ev.job_id)
        if run is None:
            return
        if ev.kind == "progress":
            run.pending_progress = (ev.fraction, ev.message)
            return
        self._running.pop(ev.job_id, None)
        elapsed = time.monotonic() - run.started
        if ev.kind == "canceled":
            if run.cancel_reason == "timeout":
                msg = f"timed out after {elapsed:.1f} s (limit {run.deadline - run.started:.1f} s)"
                self._finish(run, "failed", msg, error={"code": "TIMEOUT", "message": msg})
            else:
                self._finish_canceled(ev.job_id, ev.message or "canceled", run=run)
        elif ev.kind == "error":
            err = dict(ev.error or {"code": "ERROR", "message": "unknown error"})
            if run.cancel_reason == "canceled" and err.get("code") == "WORKER_CRASHED":
                self._finish_canceled(ev.job_id, "canceled (its worker was stopped)", run=run)
                return
            self._finish(run, "failed", err.get("message", "error"), error=err)
        else:
            self._finish_result(run, ev.result)

    def _finish_result(self, run: _Running, packaged: Any) -> None:
        """Store a result packaged by the worker (service.jobs.results.package): canonical text, hash, summary."""
        if not isinstance(packaged, dict) or "text" not in packaged:
            msg = "the executor returned a result that was not packaged"
            self._finish(run, "failed", msg, error={"code": "INVALID_RESULT", "message": msg})
            return
        summary, sha = packaged["summary"], packaged["sha256"]
        extra: dict[str, Any] = {}
        if summary.get("seed") is not None:
            extra["seed"] = summary["seed"]
        if summary.get("robot"):
            extra["robot"] = summary["robot"]
            extra["robot_sha256"] = summary.get("robot_sha256") or robot_sha256(summary["robot"])
        text = packaged["text"]
        if run.kind in ("plan", "recover"):  # a recover job's result is a plan, approved and dispatched as one
            if summary.get("status") == "infeasible":
                err = summary.get("failure") or {"code": "INFEASIBLE", "message": ""}
                err = {"code": err["code"], "message": err["message"] or "no plan meets the constraints"}
                self._finish(run, "failed", f"infeasible: {err['code']}: {err['message']}", error=err,
                             result_text=text, extra=extra)
            elif run.kind == "plan" and self._below_floor(summary.get("threshold_m")):
                # Planned below the site's floor: a comparison, shown beside the task's plan, never for the robot.
                extra.update(plan_sha256=sha, comparison=True)
                thr, floor = summary["threshold_m"], self.policy.margin_floor_m
                self._finish(run, "succeeded", f"a comparison: planned at {thr * 1000:.1f} mm, below the "
                             f"{floor * 1000:.1f} mm floor of the {self.policy.describe()}; never approved or dispatched",
                             result_text=text, extra=extra,
                             data={"plan_sha256": sha, "risk": summary.get("risk"), "comparison": True,
                                   "policy_sha256": self.policy.sha256()})
            else:
                extra["plan_sha256"] = sha
                self._finish(run, "planned", "planned; waiting for approval", result_text=text, extra=extra,
                             data={"plan_sha256": sha, "risk": summary.get("risk")})
        else:
            self._finish(run, "succeeded", "survey finished", result_text=text, extra=extra)

    def _below_floor(self, threshold_m: Any) -> bool:
        """Whether a plan made at ``threshold_m`` is below the safety policy's floor (a comparison)."""
        return isinstance(threshold_m, (int, float)) and self.policy.below_floor(float(threshold_m))

    def _finish(self, run: _Running, state: str, message: str, *, error: dict[str, Any] | None = None,
                result_text: str | None = None, extra: dict[str, Any] | None = None,
                data: dict[str, Any] | None = None) -> None:
        if error is not None:
            error = {k: v for k, v in error.items() if k in ("code", "message", "traceback")}
        try:
            self.store.finish_planning(run.job_id, self.owner, state, message=message,
                                       planning_s=time.monotonic() - run.started, result_text=result_text,
                                       error=error, extra=extra, data=data)
        except Exception as exc:
            reason = self.storage.note_failure(exc, f"storing job {run.job_id}'s outcome") if self.storage else None
            if reason is None:
                raise
            self._unrecorded[run.job_id] = (run, reason)  # failed with the reason as soon as that can be written
            self._fail_for_storage(reason)

    def _fail_for_storage(self, reason: str | None) -> None:
        """Fail every running job with the storage's reason (stopping its worker), and write down the
        failures that could not be written before; the reserve file makes room for them."""
        for job_id, run in list(self._running.items()):
            if reason is not None:
                self._running.pop(job_id)
                self.executor.cancel(job_id)
                self._unrecorded[job_id] = (run, reason)
        if not self._unrecorded:
            return
        if self.storage is not None:
            self.storage.release_reserve()
        for job_id, (run, why) in list(self._unrecorded.items()):
            try:
                self.store.finish_planning(job_id, self.owner, "failed", message=f"failed: {why}",
                                           planning_s=time.monotonic() - run.started,
                                           error={"code": "STORAGE_UNAVAILABLE", "message": why})
            except Exception as exc:  # noqa: BLE001 - still no room: tried again at the next step
                if storage_trouble(exc) is None:
                    raise
                continue
            del self._unrecorded[job_id]
            log.error("job %s failed: %s", job_id, why)

    def _finish_canceled(self, job_id: str, message: str, run: _Running | None = None) -> None:
        run = run or self._running.pop(job_id, None)
        self._running.pop(job_id, None)
        if run is None:
            return
        self._finish(run, "canceled", message)

    # ------------------------------------------------------- flags/progress
    def _flush_progress(self, now: float) -> None:
        for run in self._running.values():
            if run.pending_progress is not None and now - run.last_progress_store >= self.settings.progress_min_interval_s:
                fraction, message = run.pending_progress
                run.pending_progress = None
                run.last_progress_store = now
                self.store.report_progress(run.job_id, self.owner, fraction, message)

    def _check_flags_and_deadlines(self, now: float) -> None:
        if not self._running:
            return
        flags = self.store.flags(list(self._running))
        for job_id, run in list(self._running.items()):
            row = flags.get(job_id)
            if row is None or row["state"] != "planning" or row["owner"] != self.owner:
                # Someone else moved the job (recovered after a lost lease): stop our copy.
                self.executor.cancel(job_id)
                run.cancel_reason = run.cancel_reason or "lost"
                continue
            if run.cancel_reason is None and row["cancel_requested"]:
                run.cancel_reason = "canceled"
                self.executor.cancel(job_id)
            elif run.cancel_reason is None and now >= run.deadline:
                run.cancel_reason = "timeout"
                self.executor.cancel(job_id)
