"""The one call site of the audit trail: job events -> the job's MCAP audit file.

Every state change, request, plan, approval, gate verdict and dispatched segment
is first an event row in the job store (the system of record). A single pump
per service tails those rows and hands each to ``service.audit.AuditWriter``
(through ``AuditWriter(path, job_id, carried=...)``, ``.record(kind, payload,
log_time_ns) -> chain head`` and ``.close()``), then stores the chain head, the
file path and the last recorded event in the job row.

Each record is logged at the time of its event (the event row's time; an
approval at the moment it was given), not when the pump writes it. A plan or
survey document goes in once, as the stored canonical text (never re-serialised),
with the state change that ended planning; an expired approval sends the job back
to planned without a second copy.

After a crash the interrupted file is left as it is (it reads up to its last
record). The job continues in a new file ``<job>.<n>.mcap`` that first carries the
interrupted file's records up to the stored chain head, unchanged, then a
``continued`` record naming that file: the newest file holds the job's whole chain,
and ``GET /v1/jobs/{id}/audit`` serves it as the one download.
"""

from __future__ import annotations

import logging
import threading
from datetime import datetime
from pathlib import Path
from typing import Any

import sqlalchemy as sa

from schemas.jobs import TERMINAL_STATES

from ..store.repo import JobStore
from ..store.tables import job_events, jobs
from .encoding import RawJson
from .topics import KIND_CONTINUED
from .verify import verify
from .writer import AuditWriter

log = logging.getLogger("regrasp.audit")

PUMP_PERIOD_S = 0.2
#: Bridge events that can come after a job ended and are still recorded (in a continuation file): the stop
#: sent again to a controller that was lost during the job and came back.
AFTER_END_EVENTS = frozenset({"stop_resent"})


#: States with which planning ends and the result document is stored (a survey's only end is succeeded).
_RESULT_STATES = ("planned", "failed", "succeeded")
#: A record: (kind, payload, log time in Unix ns).
Record = tuple[str, dict[str, Any], int]


def _ns(at: datetime) -> int:
    """Unix nanoseconds of an aware datetime, exactly (no float rounding)."""
    delta = at - datetime(1970, 1, 1, tzinfo=at.tzinfo)
    return (delta.days * 86_400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1_000


def _iso_ns(text: Any, default: int) -> int:
    try:
        return _ns(datetime.fromisoformat(str(text)))
    except (TypeError, ValueError):
        return default


def _result_recorded_before(store: JobStore, job_id: str, event_id: int) -> bool:
    """An earlier state event of the job already ended planning (this one is an expiry's return to planned)."""
    with store.engine.connect() as conn:
        first = conn.execute(
            sa.select(job_events.c.id).where(job_events.c.job_id == job_id, job_events.c.kind == "state",
                                              job_events.c.state.in_(_RESULT_STATES), job_events.c.id < event_id)
            .limit(1)).scalar()
    return first is not None


def records_for_event(event: dict[str, Any], job: dict[str, Any], store: JobStore) -> list[Record]:
    """The audit records one job event becomes, each with the time of what it records."""
    data = dict(event.get("data") or {})
    at = _ns(event["at"])
    base = {"event_id": event["id"], "at": event["at"].isoformat(), "job_id": event["job_id"],
            "message": event.get("message")}
    kind = event["kind"]
    out: list[Record] = []
    if kind == "state":
        state = event.get("state")
        if state == "queued" and "request" in data:
            out.append(("request", {**base, "kind": job["kind"], "request": data["request"],
                                    "submitter": data.get("submitter")}, at))
        out.append(("state", {**base, "state": state, "data": data}, at))
        ends_planning = state in ("planned", "failed") or (state == "succeeded" and job["kind"] == "survey")
        if ends_planning and not _result_recorded_before(store, event["job_id"], event["id"]):
            text = store.result_text(event["job_id"])
            if text is not None:
                out.append(("plan" if job["kind"] in ("plan", "recover") else "survey",
                            {**base, "plan_sha256": job.get("plan_sha256"), "document": RawJson(text)}, at))
        if "approval" in data:
            approval = data["approval"]
            out.append(("approval", {**base, **approval}, _iso_ns(approval.get("approved_at"), at)))
        if "verdict" in data and data["verdict"] is not None:
            out.append(("gate_verdict", {**base, "verdict": data["verdict"]}, at))
    elif kind == "bridge":
        out.append((str(data.get("event") or "bridge"), {**base, "data": data.get("payload", data)}, at))
    elif kind == "progress":
        out.append(("progress", {**base, "progress": event.get("progress")}, at))
    else:
        out.append(("log", {**base, "kind": kind, "data": data}, at))
    return out


class JobAuditor:
    """Tails the event table and writes one audit file per job (runs in the audit process, :class:`AuditProcess`)."""

    def __init__(self, store: JobStore, audit_dir: Path) -> None:
        self.store = store
        self.audit_dir = audit_dir
        self._writers: dict[str, tuple[Any, Path]] = {}
        self._done_upto: dict[str, int] = {}
        #: Fields of a job row not stored yet (the store failed): job id -> fields.
        self._unsaved: dict[str, dict[str, Any]] = {}
        self._cursor = 0

    def _start_cursor(self) -> int:
        with self.store.engine.connect() as conn:
            low = conn.execute(sa.select(sa.func.min(sa.func.coalesce(jobs.c.audit_event_id, 0)))
                               .where(sa.or_(jobs.c.audit_closed.is_(None), jobs.c.audit_closed.is_(False)))).scalar()
        return int(low or 0)

    def stop(self) -> None:
        """Close every open audit file."""
        for writer, _ in self._writers.values():
            try:
                writer.close()
            except Exception as exc:  # noqa: BLE001
                _log_failure("closing an audit writer failed", exc)
        self._writers.clear()

    def _drop_writer(self, job_id: str) -> None:
        """Forget a job's writer after a failed write: its file ends where it stopped (read as unfinished), and
        the job continues in a new file carrying the records up to the stored head."""
        entry = self._writers.pop(job_id, None)
        if entry is not None:
            try:
                entry[0].close()
            except Exception as exc:  # noqa: BLE001 - the file is left as a crash would leave it
                log.debug("closing the failed audit writer of %s: %s", job_id, exc)

    def _save(self, job_id: str) -> None:
        """Store the job's file, head and progress; kept and tried again at the next pump if the store fails,
        so that the stored head always catches up with the file's last record."""
        fields = self._unsaved.get(job_id)
        if fields:
            self.store.update_fields(job_id, **fields)
            self._unsaved.pop(job_id, None)

    def run(self, stop: Any, parent_pid: int, terminated: threading.Event | None = None) -> None:
        """Pump until ``stop`` (or ``terminated``, set by a signal) is set or the parent process dies (used by the
        audit process)."""
        import os

        self.audit_dir.mkdir(parents=True, exist_ok=True)
        self._cursor = self._start_cursor()
        while not stop.wait(PUMP_PERIOD_S) and not (terminated is not None and terminated.is_set()):
            if os.getppid() != parent_pid:
                # The service died (e.g. SIGKILL): leave the files as the crash left them (unfinished).
                os._exit(3)
            try:
                self.pump_once()
            except Exception as exc:  # noqa: BLE001
                _log_failure("audit pump failed", exc)
        try:
            self.pump_once()
        except Exception as exc:  # noqa: BLE001
            _log_failure("final audit pump failed", exc)
        self.stop()

    def pump_once(self) -> int:
        """Record the events stored since the last pump. The store is read once per job and written once per job
        per pump (not per event: at tens of events a second, a read and a committed write for each one kept the
        pump behind the bridge); the job row's audit fields reach the store at the end of the pump."""
        for job_id in list(self._unsaved):
            self._save(job_id)
        events = self.store.all_events_after(self._cursor)
        rows: dict[str, dict[str, Any] | None] = {}  # job id -> its row, read once in this pump
        try:
            for event in events:
                self._pump_event(event, rows)
        finally:
            for job_id in list(self._unsaved):
                self._save(job_id)
        return len(events)

    def _pump_event(self, event: dict[str, Any], rows: dict[str, dict[str, Any] | None]) -> None:
        """Record one event (its job row from ``rows``, read from the store the first time it is needed)."""
        job_id = event["job_id"]
        if job_id not in rows:
            rows[job_id] = self.store.get(job_id)
        job = rows[job_id]
        if job is None:
            self._cursor = event["id"]
            return
        done = self._done_upto.get(job_id)
        if done is None:
            done = job.get("audit_event_id") or 0
            self._done_upto[job_id] = done
        after_end = (job.get("audit_closed") and event["kind"] == "bridge"
                     and (event.get("data") or {}).get("event") in AFTER_END_EVENTS)
        if event["id"] <= done or (job.get("audit_closed") and not after_end):
            self._cursor = event["id"]
            return
        try:
            writer, path = self._writer(job, "recorded after the job ended" if after_end else None)
            head = None
            for kind, payload, at_ns in records_for_event(event, job, self.store):
                head = writer.record(kind, payload, at_ns)
            closing = (event["kind"] == "state" and event.get("state") in TERMINAL_STATES) or after_end
            if closing:
                writer.close()
                self._writers.pop(job_id, None)
        except Exception:
            # The event is recorded again (in a continuation file) at the next pump; the cursor stays before it.
            self._drop_writer(job_id)
            raise
        self._done_upto[job_id] = event["id"]
        self._cursor = event["id"]
        # The stored file and head are always the newest file's and its last record's (also for a record
        # added after the job ended): `regrasp audit verify --head` agrees with the job's stored head.
        fields: dict[str, Any] = {"audit_event_id": event["id"], "audit_path": str(path)}
        if isinstance(head, str):
            fields["audit_head"] = head
        if closing:
            fields["audit_closed"] = True
        self._unsaved[job_id] = {**self._unsaved.get(job_id, {}), **fields}
        job.update(fields)  # this pump's later events of the job see the row as it will be stored

    def _writer(self, job: dict[str, Any], continued_because: str | None = None) -> tuple[Any, Path]:
        job_id = job["id"]
        if job_id in self._writers:
            return self._writers[job_id]
        previous = job.get("audit_path")
        path = self.audit_dir / f"{job_id}.mcap"
        n = 1
        while path.exists():
            path = self.audit_dir / f"{job_id}.{n}.mcap"
            n += 1
        carried = _carried_records(previous, job.get("audit_head")) if previous else []
        writer = AuditWriter(path, job_id, robot_name=job.get("robot"), carried=carried)
        if previous:
            writer.record(KIND_CONTINUED, {
                "job_id": job_id, "previous_file": Path(previous).name, "previous_head": job.get("audit_head"),
                "carried_records": len(carried),
                "reason": (continued_because or "the service restarted; the previous file ends where it stopped")
                          + ("" if carried else " (its records could not be carried over: see the previous file)")})
            # The new file holds the chain from now on: point the job at it at once.
            self.store.update_fields(job_id, audit_path=str(path), audit_head=writer.head)
        self._writers[job_id] = (writer, path)
        return writer, path


def _log_failure(what: str, exc: BaseException) -> None:
    """One line for a disk or store that will not take writes (the service's health says so), a traceback else."""
    from ..store.health import storage_trouble

    trouble = storage_trouble(exc)
    if trouble is not None:
        log.error("%s: the disk is %s (%s); retrying", what, trouble, str(exc).splitlines()[0][:200] if str(exc) else "")
    else:
        log.exception(what)


def _carried_records(previous: str, head: str | None) -> list[Any]:
    """The verified records of ``previous`` up to the stored ``head`` (empty when they cannot be trusted).

    Records after the head were written by a pump that died before it stored them: their events
    are recorded again in the new file, so they are not carried.
    """
    path = Path(previous)
    if not head or not path.is_file():
        return []
    try:
        result = verify(path, keep_raw=True)
    except (OSError, ValueError) as exc:
        log.warning("audit: cannot read %s to continue it (%s)", path, exc)
        return []
    for k, entry in enumerate(result.entries):
        if entry.digest == head:
            return result.entries[: k + 1]
    log.warning("audit: the stored head %s is not in the verified chain of %s (%s); starting a new chain",
                head, path, result.detail)
    return []


def _audit_process_main(database_url: str, audit_dir: str, parent_pid: int, stop: Any) -> None:
    """Entry point of the audit process: the pump runs here, away from the API's GIL.

    Writing a plan's Foxglove playback (thousands of messages) and hashing large
    records would otherwise stall the API process, whose robot bridge must answer
    controller heartbeats within a fraction of a second.
    """
    import os
    import signal

    from ..store import make_engine

    # A SIGTERM (the service's process group stopped) only marks the stop: setting the multiprocessing Event from
    # the handler could deadlock on the Event's own lock, which the interrupted wait may be holding.
    terminated = threading.Event()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda *_: terminated.set())
    engine = make_engine(database_url, pool_size=2)
    auditor = JobAuditor(JobStore(engine), Path(audit_dir))
    auditor.run(stop, parent_pid, terminated)
    engine.dispose()
    os._exit(0)


class AuditProcess:
    """The audit pump in its own spawn process (the default inside ``regrasp serve``)."""

    def __init__(self, database_url: str, audit_dir: Path) -> None:
        import multiprocessing as mp

        self._ctx = mp.get_context("spawn")
        self._stop = self._ctx.Event()
        self._args = (database_url, str(audit_dir))
        self._proc: Any = None

    def start(self) -> None:
        import os

        self._proc = self._ctx.Process(target=_audit_process_main, args=(*self._args, os.getpid(), self._stop),
                                       name="regrasp-audit", daemon=True)
        self._proc.start()

    def stop(self) -> None:
        if self._proc is None:
            return
        self._stop.set()
        self._proc.join(10)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(2)
