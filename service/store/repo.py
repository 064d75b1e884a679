"""The job repository: every read and state change of a job goes through here.

Every state change is a compare-and-set (``UPDATE ... WHERE state IN (...)``)
written in the same transaction as its event row, so two actors (an API replica
and a runner, or two runners) can never both move one job, and the event
history is exactly the sequence of states the job went through. Claims use
``FOR UPDATE SKIP LOCKED`` on PostgreSQL; on SQLite the conditional update is
enough because SQLite has a single writer.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from datetime import datetime, timedelta, timezone
from typing import Any, Callable, Iterable, Iterator, Sequence

import sqlalchemy as sa
from sqlalchemy.exc import IntegrityError

from schemas import fast_json
from schemas.jobs import TERMINAL_STATES

from ..errors import RegraspServiceError
from .tables import job_events, job_results, jobs


def utcnow() -> datetime:
    return datetime.now(timezone.utc)


class Conflict(RegraspServiceError):
    """The job is not in a state that allows the action (HTTP 409)."""


class IdempotencyMismatch(RegraspServiceError):
    """An Idempotency-Key was reused with a different request body."""


class QueueFull(RegraspServiceError):
    """The queue holds ``depth`` jobs, at or past the limit a new submission was checked against (HTTP 429)."""

    def __init__(self, depth: int) -> None:
        super().__init__(f"the queue holds {depth} jobs")
        self.depth = depth


class UserQueueFull(RegraspServiceError):
    """The submitter has ``count`` jobs queued or planning, at or past their own limit (HTTP 429)."""

    def __init__(self, count: int) -> None:
        super().__init__(f"the submitter has {count} jobs queued or planning")
        self.count = count


#: Hot-path statements, built once: SQLAlchemy then reuses their compiled form (the API's latency budget).
_GET_JOB = sa.select(jobs).where(jobs.c.id == sa.bindparam("job_id"))
_GET_RESULT = sa.select(job_results.c.result).where(job_results.c.job_id == sa.bindparam("job_id"))
_QUEUE_DEPTH = sa.select(sa.func.count()).select_from(jobs).where(jobs.c.state == "queued")
_USER_PENDING = sa.select(sa.func.count()).select_from(jobs).where(
    jobs.c.submitter == sa.bindparam("submitter"), jobs.c.state.in_(("queued", "planning")))
_BY_KEY = sa.select(jobs).where(jobs.c.submitter == sa.bindparam("submitter"),
                                jobs.c.idempotency_key == sa.bindparam("key"))
_INSERT_JOB = jobs.insert()
_INSERT_EVENT = job_events.insert()
_EVENT_FIELDS = ("job_id", "at", "kind", "state", "progress", "message", "data")


class JobStore:
    """All queries of the job store, over one SQLAlchemy engine."""

    def __init__(self, engine: sa.Engine) -> None:
        self.engine = engine
        self.is_postgres = engine.dialect.name == "postgresql"
        # SQLite has one writer; threads of this process queue on a lock instead of on SQLite's busy
        # handler, which backs off by sleeping up to 100 ms (ruinous for the API's latency under load).
        self._write_lock: Any = threading.Lock() if engine.dialect.name == "sqlite" else contextlib.nullcontext()

    @contextlib.contextmanager
    def _begin(self) -> Iterator[sa.Connection]:
        """A write transaction (serialised within this process on SQLite)."""
        with self._write_lock, self.engine.begin() as conn:
            yield conn

    # ----------------------------------------------------------------- events
    @staticmethod
    def _event(conn: sa.Connection, job_id: str, kind: str, *, state: str | None = None,
               progress: float | None = None, message: str | None = None,
               data: dict[str, Any] | None = None, at: datetime | None = None) -> None:
        conn.execute(_INSERT_EVENT, {"job_id": job_id, "at": at or utcnow(), "kind": kind, "state": state,
                                     "progress": progress, "message": message, "data": data or {}})

    def add_event(self, job_id: str, kind: str, *, message: str | None = None,
                  data: dict[str, Any] | None = None) -> None:
        with self._begin() as conn:
            self._event(conn, job_id, kind, message=message, data=data)

    def events_after(self, job_id: str, after_id: int = 0, limit: int = 500) -> list[dict[str, Any]]:
        with self.engine.connect() as conn:
            rows = conn.execute(
                sa.select(job_events).where(job_events.c.job_id == job_id, job_events.c.id > after_id)
                .order_by(job_events.c.id).limit(limit)
            ).mappings().all()
        return [dict(r) for r in rows]

    def all_events_after(self, after_id: int, limit: int = 1000) -> list[dict[str, Any]]:
        with self.engine.connect() as conn:
            rows = conn.execute(
                sa.select(job_events).where(job_events.c.id > after_id).order_by(job_events.c.id).limit(limit)
            ).mappings().all()
        return [dict(r) for r in rows]

    # ------------------------------------------------------------------ reads
    def get(self, job_id: str) -> dict[str, Any] | None:
        with self.engine.connect() as conn:
            row = conn.execute(_GET_JOB, {"job_id": job_id}).mappings().first()
        return dict(row) if row else None

    def result(self, job_id: str) -> dict[str, Any] | None:
        with self.engine.connect() as conn:
            text = conn.execute(_GET_RESULT, {"job_id": job_id}).scalar()
        return None if text is None else fast_json.loads(text)  # a plan can be 10 MB: orjson, json's results

    def result_text(self, job_id: str) -> str | None:
        """The stored result document as its JSON text (served verbatim, never re-parsed)."""
        with self.engine.connect() as conn:
            return conn.execute(_GET_RESULT, {"job_id": job_id}).scalar()

    def list(self, *, state: str | None = None, kind: str | None = None, submitter: str | None = None,
             limit: int = 50, offset: int = 0) -> tuple[list[dict[str, Any]], int]:
        conds = []
        if state:
            conds.append(jobs.c.state == state)
        if kind:
            conds.append(jobs.c.kind == kind)
        if submitter:
            conds.append(jobs.c.submitter == submitter)
        with self.engine.connect() as conn:
            total = conn.execute(sa.select(sa.func.count()).select_from(jobs).where(*conds)).scalar_one()
            rows = conn.execute(
                sa.select(jobs).where(*conds).order_by(jobs.c.seq.desc()).limit(limit).offset(offset)
            ).mappings().all()
        return [dict(r) for r in rows], int(total)

    def count_by_state(self) -> dict[tuple[str, str], int]:
        with self.engine.connect() as conn:
            rows = conn.execute(
                sa.select(jobs.c.kind, jobs.c.state, sa.func.count()).group_by(jobs.c.kind, jobs.c.state)
            ).all()
        return {(k, s): int(n) for k, s, n in rows}

    def planning_stats(self, bounds: Sequence[float]) -> list[dict[str, Any]]:
        """Finished planning by kind and outcome: count, summed time and cumulative counts at ``bounds`` (s).

        Every runner (in ``regrasp serve`` or a separate ``regrasp worker``) writes its jobs' planning
        time and outcome to the store, so any API replica's /metrics reports all of them.
        """
        known = jobs.c.planning_s.is_not(None)
        cols = [jobs.c.kind, jobs.c.planning_outcome, sa.func.count(),
                sa.func.coalesce(sa.func.sum(jobs.c.planning_s), 0.0)]
        cols += [sa.func.sum(sa.case((sa.and_(known, jobs.c.planning_s <= b), 1), else_=0)) for b in bounds]
        cols.append(sa.func.sum(sa.case((known, 1), else_=0)))
        query = (sa.select(*cols).where(jobs.c.planning_outcome.is_not(None))
                 .group_by(jobs.c.kind, jobs.c.planning_outcome))
        with self.engine.connect() as conn:
            rows = conn.execute(query).all()
        return [{"kind": r[0], "outcome": r[1], "count": int(r[2]), "sum": float(r[3]),
                 "buckets": [int(v or 0) for v in r[4:4 + len(bounds)]], "timed": int(r[-1] or 0)} for r in rows]

    def queue_depth(self) -> int:
        with self.engine.connect() as conn:
            return int(conn.execute(_QUEUE_DEPTH).scalar_one())

    # --------------------------------------------------------------- creation
    def create(self, *, job_id: str, kind: str, submitter: str, request: dict[str, Any],
               request_sha256: str, idempotency_key: str | None,
               provenance: dict[str, Any], queue_limit: int | None = None,
               user_limit: int | None = None) -> tuple[dict[str, Any], bool]:
        """Insert a queued job; with an idempotency key already used by this submitter, return that job instead.

        The replay lookup, the queue-limit check (:class:`QueueFull`), the submitter's own limit on
        jobs queued or planning (:class:`UserQueueFull`) and the insert share one transaction: a
        submission costs one connection and one write, and on SQLite the limits are exact.
        """
        now = utcnow()
        values = {c.name: None for c in jobs.columns if c.name != "seq"}
        values.update(
            id=job_id, kind=kind, state="queued", progress=0.0, message="queued", submitter=submitter,
            request=request, request_sha256=request_sha256, idempotency_key=idempotency_key,
            cancel_requested=False, stop_requested=False, attempts=0, created_at=now, updated_at=now,
            **provenance,
        )
        try:
            with self._begin() as conn:
                if idempotency_key is not None:
                    existing = conn.execute(_BY_KEY, {"submitter": submitter, "key": idempotency_key}).mappings().first()
                    if existing is not None:
                        return self._replay(dict(existing), request_sha256), False
                if queue_limit is not None:
                    depth = int(conn.execute(_QUEUE_DEPTH).scalar_one())
                    if depth >= queue_limit:
                        raise QueueFull(depth)
                if user_limit is not None:
                    pending = int(conn.execute(_USER_PENDING, {"submitter": submitter}).scalar_one())
                    if pending >= user_limit:
                        raise UserQueueFull(pending)
                conn.execute(_INSERT_JOB, values)
                self._event(conn, job_id, "state", state="queued", progress=0.0, message=f"{kind} job submitted by {submitter}",
                            data={"request": request, "submitter": submitter, "idempotency_key": idempotency_key}, at=now)
        except IntegrityError:  # another replica inserted the same key between our lookup and insert
            if idempotency_key is None:
                raise
            existing = self._by_key(submitter, idempotency_key)
            if existing is None:
                raise
            return self._replay(existing, request_sha256), False
        return {"seq": None, **values}, True

    def _by_key(self, submitter: str, key: str) -> dict[str, Any] | None:
        with self.engine.connect() as conn:
            row = conn.execute(_BY_KEY, {"submitter": submitter, "key": key}).mappings().first()
        return dict(row) if row else None

    @staticmethod
    def _replay(existing: dict[str, Any], request_sha256: str) -> dict[str, Any]:
        if existing["request_sha256"] != request_sha256:
            raise IdempotencyMismatch(
                f"Idempotency-Key {existing['idempotency_key']!r} was already used for job {existing['id']} "
                "with a different request; use a new key for a new request"
            )
        return existing

    # ------------------------------------------------------------ transitions
    def transition(self, job_id: str, from_states: Iterable[str], to_state: str, *,
                   message: str | None = None, data: dict[str, Any] | None = None,
                   expect_owner: str | None = None, event_kind: str = "state", **fields: Any) -> bool:
        """Move a job from one of ``from_states`` to ``to_state`` atomically; False if it was not in one of them."""
        now = utcnow()
        values: dict[str, Any] = {"state": to_state, "updated_at": now, **fields}
        if message is not None:
            values["message"] = message
        if to_state in TERMINAL_STATES:
            values.setdefault("finished_at", now)
            values.setdefault("owner", None)
            values.setdefault("lease_expires_at", None)
        conds = [jobs.c.id == job_id, jobs.c.state.in_(list(from_states))]
        if expect_owner is not None:
            conds.append(jobs.c.owner == expect_owner)
        with self._begin() as conn:
            n = conn.execute(jobs.update().where(*conds).values(**values)).rowcount
            if n != 1:
                return False
            self._event(conn, job_id, event_kind, state=to_state, progress=values.get("progress"),
                        message=message, data=data, at=now)
        return True

    def begin_dispatch(self, job_id: str, *, message: str, data: dict[str, Any], owner: str,
                       lease_expires_at: datetime) -> tuple[bool, str | None]:
        """Move an approved job to dispatching unless another job of its robot is dispatching or executing.

        One transaction decides it (on PostgreSQL under a transaction-scoped advisory lock per robot, so two
        replicas cannot both see the robot free): of concurrent dispatches exactly one wins. Returns
        ``(True, None)`` for the winner, ``(False, running_job_id)`` when the robot is busy, ``(False, None)``
        when the job was no longer approved."""
        now = utcnow()
        with self._begin() as conn:
            robot = conn.execute(sa.select(jobs.c.robot).where(jobs.c.id == job_id)).scalar()
            if self.is_postgres:
                conn.execute(sa.text("SELECT pg_advisory_xact_lock(hashtext(:k))"), {"k": f"dispatch:{robot}"})
            running = conn.execute(
                sa.select(jobs.c.id).where(jobs.c.state.in_(["dispatching", "executing"]),
                                           jobs.c.robot.is_(None) if robot is None else jobs.c.robot == robot,
                                           jobs.c.id != job_id).limit(1)
            ).scalar()
            if running is not None:
                return False, running
            n = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.state == "approved")
                             .values(state="dispatching", updated_at=now, message=message, owner=owner,
                                     lease_expires_at=lease_expires_at)).rowcount
            if n != 1:
                return False, None
            self._event(conn, job_id, "state", state="dispatching", message=message, data=data, at=now)
        return True, None

    def update_fields(self, job_id: str, **fields: Any) -> None:
        with self._begin() as conn:
            conn.execute(jobs.update().where(jobs.c.id == job_id).values(**fields))

    # ------------------------------------------------------------------ claim
    def claim(self, owner: str, limit: int, lease_s: float, provenance: dict[str, Any] | None = None) -> list[dict[str, Any]]:
        """Take up to ``limit`` queued jobs, oldest first, for this runner."""
        if limit <= 0:
            return []
        sel = sa.select(jobs.c.seq).where(jobs.c.state == "queued").order_by(jobs.c.seq).limit(limit)
        if self.is_postgres:
            sel = sel.with_for_update(skip_locked=True)
        claimed: list[str] = []
        now = utcnow()
        with self._begin() as conn:
            seqs = conn.execute(sel).scalars().all()
            for seq in seqs:
                values = dict(state="planning", owner=owner, lease_expires_at=now + timedelta(seconds=lease_s),
                              started_at=now, updated_at=now, attempts=jobs.c.attempts + 1,
                              progress=0.0, message="planning", **(provenance or {}))
                job_id = conn.execute(
                    jobs.update().where(jobs.c.seq == seq, jobs.c.state == "queued").values(**values)
                    .returning(jobs.c.id)
                ).scalar()
                if job_id is not None:
                    claimed.append(job_id)
                    self._event(conn, job_id, "state", state="planning", progress=0.0,
                                message="a worker started planning", data={"runner": owner}, at=now)
        return [r for r in (self.get(j) for j in claimed) if r is not None]

    def renew(self, owner: str, job_ids: Sequence[str], lease_s: float) -> None:
        if not job_ids:
            return
        with self._begin() as conn:
            conn.execute(jobs.update().where(jobs.c.id.in_(list(job_ids)), jobs.c.owner == owner)
                         .values(lease_expires_at=utcnow() + timedelta(seconds=lease_s)))

    def flags(self, job_ids: Sequence[str]) -> dict[str, dict[str, Any]]:
        """State and cancel/stop flags of the given jobs (polled by runners and executions)."""
        if not job_ids:
            return {}
        with self.engine.connect() as conn:
            rows = conn.execute(
                sa.select(jobs.c.id, jobs.c.state, jobs.c.owner, jobs.c.cancel_requested, jobs.c.stop_requested)
                .where(jobs.c.id.in_(list(job_ids)))
            ).mappings().all()
        return {r["id"]: dict(r) for r in rows}

    def report_progress(self, job_id: str, owner: str, fraction: float, message: str) -> bool:
        now = utcnow()
        with self._begin() as conn:
            n = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.owner == owner, jobs.c.state == "planning")
                             .values(progress=fraction, message=message, updated_at=now)).rowcount
            if n == 1:
                self._event(conn, job_id, "progress", state="planning", progress=fraction, message=message, at=now)
        return n == 1

    def finish_planning(self, job_id: str, owner: str | None, to_state: str, *, message: str,
                        planning_s: float | None, result_text: str | None = None,
                        error: dict[str, Any] | None = None, extra: dict[str, Any] | None = None,
                        data: dict[str, Any] | None = None) -> bool:
        """End the planning phase (planned, succeeded, failed, canceled) and store the result, in one transaction.

        The runner that planned the job and recovery (its runner is gone) both end planning here, so
        every job whose planning ended carries its outcome (the state it went to) and its planning
        time in s (None if unknown): /metrics of any API replica reads them from the row.
        """
        now = utcnow()
        values: dict[str, Any] = dict(state=to_state, message=message, error=error, updated_at=now, owner=None,
                                      lease_expires_at=None, **(extra or {}),
                                      planning_outcome=to_state, planning_s=planning_s)
        if to_state in ("planned", "succeeded"):
            values["progress"] = 1.0
        if to_state in TERMINAL_STATES:
            values["finished_at"] = now
        with self._begin() as conn:
            n = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.owner == owner, jobs.c.state == "planning")
                             .values(**values)).rowcount
            if n != 1:
                return False
            if result_text is not None:
                conn.execute(job_results.insert().values(job_id=job_id, result=result_text))
            self._event(conn, job_id, "state", state=to_state, progress=values.get("progress"), message=message,
                        data={**(data or {}), **({"error": error} if error else {})}, at=now)
        return True

    # --------------------------------------------------------------- cancel
    def request_cancel(self, job_id: str, by: str, reason: str | None) -> dict[str, Any]:
        """Cancel a job: at once unless it is planning, where the runner is asked to stop it."""
        note = f"canceled by {by}" + (f": {reason}" if reason else "")
        for _ in range(5):  # a claim can race with us; retry on the new state
            job = self.get(job_id)
            if job is None:
                raise KeyError(job_id)
            state = job["state"]
            if state in ("queued", "planned", "approved"):
                if self.transition(job_id, [state], "canceled", message=note, data={"by": by, "reason": reason},
                                   cancel_requested=True):
                    return self.get(job_id) or job
            elif state == "planning":
                if job["cancel_requested"]:
                    return job
                with self._begin() as conn:
                    n = conn.execute(jobs.update().where(jobs.c.id == job_id, jobs.c.state == "planning")
                                     .values(cancel_requested=True, updated_at=utcnow())).rowcount
                    if n == 1:
                        self._event(conn, job_id, "note", state="planning", message=f"cancel requested by {by}",
                                    data={"by": by, "reason": reason})
                if n == 1:
                    return self.get(job_id) or job
            else:
                raise Conflict(f"job {job_id} is {state}; only a job that is queued, planning, planned or approved "
                               "can be canceled (use stop during execution)")
        raise Conflict(f"job {job_id} changed state repeatedly while canceling; try again")

    # ------------------------------------------------------------- recovery
    def recover(self, is_owner_dead: Callable[[str], bool], max_attempts: int) -> list[tuple[str, str]]:
        """Account for jobs whose runner or executing process is gone: re-queue, fail, cancel or abort them."""
        now = utcnow()
        with self.engine.connect() as conn:
            rows = conn.execute(
                sa.select(jobs.c.id, jobs.c.state, jobs.c.owner, jobs.c.lease_expires_at, jobs.c.attempts,
                          jobs.c.cancel_requested, jobs.c.started_at)
                .where(jobs.c.state.in_(["planning", "dispatching", "executing"]))
            ).mappings().all()
        actions: list[tuple[str, str]] = []
        for r in rows:
            owner = r["owner"] or ""
            expired = r["lease_expires_at"] is None or r["lease_expires_at"] < now
            if not (expired or is_owner_dead(owner)):
                continue
            fields = dict(owner=None, lease_expires_at=None)
            data = {"recovered_from": r["state"]}
            if r["state"] == "planning" and (r["cancel_requested"] or r["attempts"] >= max_attempts):
                # Planning ends here, not in a runner: finish_planning records its outcome for the metrics.
                if r["cancel_requested"]:
                    to, msg, error = "canceled", "canceled (its runner stopped before it could finish)", None
                else:
                    to, msg = "failed", (f"interrupted {r['attempts']} times: its runner stopped while planning "
                                         f"(last runner {owner or '?'})")
                    error = {"code": "INTERRUPTED", "message": msg}
                planning_s = (now - r["started_at"]).total_seconds() if r["started_at"] else None
                ok = self.finish_planning(r["id"], r["owner"], to, message=msg, planning_s=planning_s, error=error,
                                          data=data)
            else:
                if r["state"] == "planning":
                    to, msg = "queued", (f"re-queued: its runner {owner or '?'} stopped while planning "
                                          f"(attempt {r['attempts']} of {max_attempts})")
                    extra: dict[str, Any] = {"progress": 0.0, "started_at": None}
                else:
                    to, msg = "aborted", f"execution interrupted: the process that drove it ({owner or '?'}) stopped"
                    extra = {"error": {"code": "INTERRUPTED", "message": msg}}
                ok = self.transition(r["id"], [r["state"]], to, message=msg, data=data, expect_owner=r["owner"],
                                     **fields, **extra)
            if ok:
                actions.append((r["id"], to))
        return actions

    def expire_approvals(self, job_id: str | None = None) -> list[str]:
        """Send approved jobs whose approval expired back to planned."""
        now = utcnow()
        conds = [jobs.c.state == "approved", jobs.c.approval_expires_at < now]
        if job_id is not None:
            conds.append(jobs.c.id == job_id)
        with self.engine.connect() as conn:
            ids = conn.execute(sa.select(jobs.c.id).where(*conds)).scalars().all()
        done = []
        for jid in ids:
            if self.transition(jid, ["approved"], "planned", message="approval expired; the plan needs a new approval",
                               approved_by=None, approved_at=None, approval_expires_at=None,
                               approved_sha256=None, approval_comment=None,
                               data={"reason": "approval expired"}):
                done.append(jid)
        return done


def this_host() -> str:
    return socket.gethostname()
