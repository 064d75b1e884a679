"""One dispatch at a time, decided in the job store: of concurrent dispatches of a robot's approved jobs exactly
one moves to dispatching, on SQLite and on a real PostgreSQL server (each thread on its own connection)."""

from __future__ import annotations

import shutil
import tempfile
import threading
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Iterator

import pytest

from service.store import JobStore, make_engine, migrate
from service.store.tables import jobs

THREADS = 8


def _approved_jobs(store: JobStore, n: int, robot: str = "hrp5p") -> list[str]:
    ids = []
    for _ in range(n):
        job_id = str(uuid.uuid4())
        store.create(job_id=job_id, kind="plan", submitter="alice", request={"scenario": "x"}, request_sha256="0" * 64,
                     idempotency_key=None, provenance={"robot": robot, "seed": None, "code_version": None,
                                                       "robot_sha256": None, "library_versions": {}})
        store.update_fields(job_id, state="approved")
        ids.append(job_id)
    return ids


def _race(store: JobStore, job_ids: list[str]) -> list[tuple[str, bool, str | None]]:
    barrier = threading.Barrier(len(job_ids))
    results: list[tuple[str, bool, str | None]] = []
    lock = threading.Lock()
    lease = datetime.now(timezone.utc) + timedelta(minutes=1)

    def go(job_id: str) -> None:
        barrier.wait()
        ok, running = store.begin_dispatch(job_id, message="dispatched", data={}, owner="test", lease_expires_at=lease)
        with lock:
            results.append((job_id, ok, running))

    threads = [threading.Thread(target=go, args=(j,)) for j in job_ids]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    return results


def _check(store: JobStore, ids: list[str], results: list[tuple[str, bool, str | None]]) -> None:
    winners = [j for j, ok, _ in results if ok]
    assert len(winners) == 1, results
    winner = winners[0]
    for job_id, ok, running in results:
        if not ok:
            assert running == winner or (job_id == winner and running is None), (job_id, running)
    states = {j: store.get(j)["state"] for j in ids}
    assert states.pop(winner) == "dispatching" and set(states.values()) <= {"approved"}
    # Another robot's job is not held back by this one.
    other = _approved_jobs(store, 1, robot="jvrc1")[0]
    assert store.begin_dispatch(other, message="m", data={}, owner="t",
                                lease_expires_at=datetime.now(timezone.utc) + timedelta(minutes=1)) == (True, None)


def test_concurrent_dispatches_on_sqlite(tmp_path: Path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.sqlite'}")
    migrate(engine)
    store = JobStore(engine)
    ids = _approved_jobs(store, THREADS - 2)
    _check(store, ids, _race(store, ids + ids[:2]))  # two of them dispatched twice


@pytest.fixture(scope="module")
def pg_url() -> Iterator[str]:
    pgserver = pytest.importorskip("pgserver", reason="pgserver (test extra) bundles the PostgreSQL server")
    pytest.importorskip("psycopg", reason="psycopg (test extra) is the PostgreSQL driver")
    data = tempfile.mkdtemp(prefix="regrasp-pg-")
    server = pgserver.get_server(data, cleanup_mode="stop")
    try:
        db = f"regrasp_{uuid.uuid4().hex[:8]}"
        server.psql(f"CREATE DATABASE {db};")
        yield server.get_uri(db).replace("postgresql://", "postgresql+psycopg://", 1)
    finally:
        server.cleanup()
        shutil.rmtree(data, ignore_errors=True)


def test_concurrent_dispatches_on_postgres(pg_url: str) -> None:
    engine = make_engine(pg_url, pool_size=THREADS)
    migrate(engine)
    store = JobStore(engine)
    for _ in range(3):  # a few rounds: a race that is lost only sometimes shows up
        ids = _approved_jobs(store, THREADS - 2)
        results = _race(store, ids + ids[:2])
        _check(store, ids, results)
        with engine.begin() as conn:  # end the round: the winner and the other robot's job
            conn.execute(jobs.update().where(jobs.c.state.in_(["dispatching", "approved"])).values(state="aborted"))
