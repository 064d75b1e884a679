"""In-process checks of settings, tokens, the store's state machine and recovery rules."""

from __future__ import annotations

import json
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from conftest import schema_drift

from service.api.auth import TokenStore, hash_token, is_loopback, make_dev_tokens
from service.api.metrics import DURATION_BUCKETS
from service.jobs.provenance import provenance
from service.settings import ServiceSettings, load_settings
from service.store import JobStore, make_engine, migrate


@pytest.fixture
def store(tmp_path: Path) -> JobStore:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.sqlite'}")
    migrate(engine)
    return JobStore(engine)


def _new(store: JobStore, key: str | None = None, request: dict | None = None) -> str:
    row, _ = store.create(job_id=str(uuid.uuid4()), kind="plan", submitter="u", request=request or {"scenario": "x"},
                          request_sha256=json.dumps(request or {}), idempotency_key=key, provenance=provenance("hrp5p", 1))
    return row["id"]


def test_settings_file_env_and_flags_in_priority_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = tmp_path / "regrasp.yaml"
    cfg.write_text("workers: 5\nqueue_limit: 7\napproval_ttl_s: 60\n")
    monkeypatch.setenv("REGRASP_QUEUE_LIMIT", "9")
    s = load_settings(cfg, workers=3)
    assert (s.workers, s.queue_limit, s.approval_ttl_s) == (3, 9, 60)
    monkeypatch.setenv("REGRASP_TOKENS", json.dumps({"secret-token-1": {"user": "ann", "roles": ["planner"]}}))
    assert ServiceSettings().tokens["secret-token-1"].user == "ann"
    with pytest.raises(ValueError, match="does not exist"):
        load_settings(tmp_path / "missing.yaml")
    monkeypatch.setenv("REGRASP_HANDLERS", json.dumps({"plan": "no-colon"}))
    with pytest.raises(ValueError, match="module:function"):
        ServiceSettings()


def test_tokens_are_kept_hashed_only() -> None:
    store = TokenStore.from_plain({"a-very-secret": {"user": "ann", "roles": ["approver"]}})
    assert store.lookup("a-very-secret").user == "ann" and store.lookup("a-very-secre") is None
    assert "a-very-secret" not in repr(store.__dict__) and hash_token("a-very-secret") in store._by_hash
    with pytest.raises(ValueError, match="shorter than 8"):
        TokenStore.from_plain({"short": {"user": "x", "roles": ["planner"]}})
    users = {e["user"]: e["roles"] for e in make_dev_tokens().values()}
    assert users["alice"] == ["planner"] and "approver" in users["bob"] and "operator" in users["bob"]
    assert is_loopback("127.0.0.1") and is_loopback("::1") and not is_loopback("0.0.0.0")


def test_transitions_are_compare_and_set(store: JobStore) -> None:
    job = _new(store)
    assert store.transition(job, ["queued"], "canceled", message="x")
    assert not store.transition(job, ["queued"], "planning")  # already moved
    assert [e["state"] for e in store.events_after(job)] == ["queued", "canceled"]
    assert store.get(job)["finished_at"] is not None


def test_recovery_requeues_then_fails_and_aborts_executions(store: JobStore) -> None:
    a, b = _new(store), _new(store)
    dead = "some-other-host:1:dead"
    assert [j["id"] for j in store.claim(dead, 2, lease_s=0.0)] == [a, b]
    store.update_fields(b, state="executing")
    actions = dict(store.recover(lambda owner: False, max_attempts=2))
    assert actions == {a: "queued", b: "aborted"}
    assert store.get(b)["error"]["code"] == "INTERRUPTED"
    store.claim(dead, 1, lease_s=0.0)
    assert dict(store.recover(lambda owner: False, max_attempts=2)) == {a: "failed"}
    assert "interrupted 2 times" in store.get(a)["error"]["message"]
    # a live lease held by a live owner is left alone
    c = _new(store)
    store.claim("live:1:x", 1, lease_s=60)
    assert store.recover(lambda owner: False, max_attempts=2) == []
    assert store.get(c)["state"] == "planning"


def test_every_end_of_planning_records_its_outcome_for_the_metrics(store: JobStore) -> None:
    dead = "some-other-host:1:dead"
    a, b, c = _new(store), _new(store), _new(store)
    store.claim(dead, 3, lease_s=0.0)
    assert store.finish_planning(a, dead, "planned", message="planned", planning_s=1.5)  # a runner's end
    store.request_cancel(b, "bob", None)  # planning: only flagged, its runner is gone
    assert dict(store.recover(lambda owner: False, max_attempts=1)) == {b: "canceled", c: "failed"}
    rows = [store.get(j) for j in (a, b, c)]
    assert [(r["state"], r["planning_outcome"]) for r in rows] == [
        ("planned", "planned"), ("canceled", "canceled"), ("failed", "failed")]
    assert rows[0]["planning_s"] == 1.5 and all(0.0 <= r["planning_s"] < 60.0 for r in rows[1:])
    stats = {r["outcome"]: (r["count"], r["buckets"]) for r in store.planning_stats([1.0, 2.0])}
    assert stats == {"planned": (1, [0, 1]), "canceled": (1, [1, 1]), "failed": (1, [1, 1])}
    # A re-queue does not end planning: nothing is recorded until the job's planning really ends.
    d = _new(store)
    store.claim(dead, 1, lease_s=0.0)
    assert store.recover(lambda owner: False, max_attempts=2) == [(d, "queued")]
    assert (store.get(d)["planning_outcome"], store.get(d)["planning_s"]) == (None, None)


def test_approval_expiry_sends_the_job_back_to_planned(store: JobStore) -> None:
    job = _new(store)
    past = datetime.now(timezone.utc) - timedelta(seconds=1)
    store.update_fields(job, state="approved", approved_by="bob", approved_at=past, approval_expires_at=past,
                        approved_sha256="0" * 64)
    assert store.expire_approvals() == [job]
    row = store.get(job)
    assert row["state"] == "planned" and row["approved_by"] is None


def test_migrations_build_the_declared_tables_and_metrics_read_indexes_only(store: JobStore) -> None:
    assert schema_drift(store.engine) == []
    # The two aggregates of a /metrics scrape, as the store sends them, are answered from covering indexes.
    sent: list[tuple[str, Any]] = []

    def record(conn, cursor, statement, parameters, context, executemany) -> None:  # type: ignore[no-untyped-def]
        sent.append((statement, parameters))

    sa.event.listen(store.engine, "before_cursor_execute", record)
    try:
        store.count_by_state()
        store.planning_stats(DURATION_BUCKETS)
    finally:
        sa.event.remove(store.engine, "before_cursor_execute", record)
    with store.engine.connect() as conn:
        by_state, stats = [" | ".join(row[-1] for row in conn.exec_driver_sql("EXPLAIN QUERY PLAN " + sql, params))
                           for sql, params in sent]
    assert by_state == "SCAN jobs USING COVERING INDEX ix_jobs_kind_state", by_state
    assert stats.startswith("SEARCH jobs USING COVERING INDEX ix_jobs_planning_stats"), stats
    assert "TEMP B-TREE" not in stats, stats


def test_idempotency_mismatch_is_refused(store: JobStore) -> None:
    from service.store.repo import IdempotencyMismatch

    first = _new(store, key="k", request={"scenario": "a"})
    assert _new(store, key="k", request={"scenario": "a"}) == first
    with pytest.raises(IdempotencyMismatch, match="different request"):
        _new(store, key="k", request={"scenario": "b"})


def test_sqlite_store_runs_in_wal_mode_with_a_busy_timeout(tmp_path: Path) -> None:
    import sqlite3
    import threading
    import time

    from service.store.db import SQLITE_BUSY_TIMEOUT_MS

    path = tmp_path / "jobs.sqlite"
    engine = make_engine(f"sqlite:///{path}")
    migrate(engine)
    with engine.connect() as one, engine.connect() as two:  # every pooled connection gets the pragmas
        for conn in (one, two):
            assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
            assert conn.exec_driver_sql("PRAGMA busy_timeout").scalar() == SQLITE_BUSY_TIMEOUT_MS
            assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
    # Another process holding the write lock: the store's write waits for it instead of failing at once.
    other = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
    assert other.execute("PRAGMA journal_mode").fetchone()[0] == "wal"  # WAL is stored in the file itself
    other.execute("BEGIN IMMEDIATE")
    hold_s = 0.5
    threading.Timer(hold_s, lambda: other.execute("COMMIT")).start()
    t0 = time.monotonic()
    _new(JobStore(engine))
    waited = time.monotonic() - t0
    other.close()
    assert waited >= hold_s * 0.8  # it waited for the lock (busy timeout 0 would raise "database is locked")
    engine.dispose()


def test_queue_limit_is_checked_in_the_insert_and_replays_still_answer(store: JobStore) -> None:
    from service.store.repo import QueueFull

    def submit(key: str) -> tuple[dict, bool]:
        return store.create(job_id=str(uuid.uuid4()), kind="plan", submitter="u", request={"scenario": key},
                            request_sha256=key, idempotency_key=key, provenance=provenance("hrp5p", 1), queue_limit=2)

    first, _ = submit("a")
    submit("b")
    with pytest.raises(QueueFull) as full:
        submit("c")
    assert full.value.depth == 2 and store.queue_depth() == 2  # nothing was inserted
    again, created = submit("a")  # a replay is an answer, not a new job: the full queue does not refuse it
    assert not created and again["id"] == first["id"]
    store.transition(first["id"], ["queued"], "canceled", message="x")
    assert submit("c")[1]  # room again


def test_audit_download_is_a_snapshot_of_a_growing_file(tmp_path):
    """A live job's audit file grows while it is served: the body is exactly the bytes present when the
    request came (an append-only file's prefix), never more than the declared length."""
    from service.api.jobs import AUDIT_CHUNK_BYTES, _snapshot

    path = tmp_path / "job.mcap"
    first = bytes(range(256)) * (AUDIT_CHUNK_BYTES // 256 + 7)  # more than one chunk
    path.write_bytes(first)
    body, size = _snapshot(str(path))
    with open(path, "ab") as f:  # the writer appends while the response is being sent
        f.write(b"later records" * 1000)
    served = b"".join(body)
    assert size == len(first) and served == first
