"""PostgreSQL job store, against a real server started by the test (the pgserver wheel bundles one).

Also the split deployment: an API replica with no workers and a separate
`regrasp worker` process sharing the PostgreSQL store, including kill -9 of the
worker process mid-job.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import uuid
from pathlib import Path
from typing import Iterator

import pytest
from conftest import ROOT, Server, schema_drift, service_env, wait_state

pgserver = pytest.importorskip("pgserver", reason="pgserver (test extra) bundles the PostgreSQL server these tests use")
pytest.importorskip("psycopg", reason="psycopg (test extra) is the PostgreSQL driver")

from service.jobs.provenance import provenance  # noqa: E402
from service.store import JobStore, make_engine, migrate  # noqa: E402


@pytest.fixture(scope="module")
def pg_server() -> Iterator[object]:
    data = tempfile.mkdtemp(prefix="regrasp-pg-")  # short path: the server's unix socket lives there
    server = pgserver.get_server(data, cleanup_mode="stop")
    try:
        yield server
    finally:
        server.cleanup()
        shutil.rmtree(data, ignore_errors=True)


def _new_database(server: object) -> str:
    db = f"regrasp_{uuid.uuid4().hex[:8]}"
    server.psql(f"CREATE DATABASE {db};")  # type: ignore[attr-defined]
    return server.get_uri(db).replace("postgresql://", "postgresql+psycopg://", 1)  # type: ignore[attr-defined]


@pytest.fixture(scope="module")
def pg_url(pg_server: object) -> str:
    return _new_database(pg_server)


def test_replicas_starting_together_migrate_once(pg_server: object) -> None:
    url = _new_database(pg_server)
    engines = [make_engine(url) for _ in range(3)]
    errors: list[BaseException] = []

    def run(engine) -> None:  # type: ignore[no-untyped-def]
        try:
            migrate(engine)
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(e,)) for e in engines]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors
    assert JobStore(engines[0]).queue_depth() == 0
    for e in engines:
        e.dispose()


def test_migrations_build_the_declared_tables(pg_server: object) -> None:
    engine = make_engine(_new_database(pg_server))
    try:
        migrate(engine)
        assert schema_drift(engine) == []  # indexes included: the /metrics aggregates' two on jobs
    finally:
        engine.dispose()


def test_migrations_and_concurrent_claims_are_exclusive(pg_url: str) -> None:
    engine = make_engine(pg_url)
    migrate(engine)
    migrate(engine)  # idempotent
    store = JobStore(engine)
    assert store.is_postgres
    ids = []
    for i in range(40):
        row, created = store.create(job_id=str(uuid.uuid4()), kind="plan", submitter="pg", request={"scenario": "x", "i": i},
                                    request_sha256=str(i), idempotency_key=f"pg-{i}", provenance=provenance("hrp5p", i))
        assert created
        ids.append(row["id"])
    again, created = store.create(job_id=str(uuid.uuid4()), kind="plan", submitter="pg", request={}, request_sha256="0",
                                  idempotency_key="pg-0", provenance=provenance("hrp5p", 0))
    assert not created and again["id"] == ids[0]
    claimed: dict[str, list[str]] = {}

    def claimer(owner: str) -> None:
        got: list[str] = []
        while True:
            batch = store.claim(owner, 3, lease_s=30)
            if not batch:
                break
            got += [j["id"] for j in batch]
        claimed[owner] = got

    threads = [threading.Thread(target=claimer, args=(f"test:{n}:x",)) for n in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    everything = [j for got in claimed.values() for j in got]
    assert sorted(everything) == sorted(ids)  # every job claimed exactly once
    engine.dispose()


def _worker(url: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "service.cli.main", "worker", "--workers", "1", "--database-url", url,
                             "--log-level", "warning"], cwd=ROOT, env=service_env(lease_s="3"),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def test_api_replica_and_separate_worker_share_the_store(pg_url: str, tmp_path: Path) -> None:
    api = Server(tmp_path, workers=0, database_url=pg_url).start()
    worker = _worker(pg_url)
    try:
        assert api.client("admin").get("/healthz").json()["database"] == "postgresql"
        with api.client("alice") as c:
            job = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-0.5"}}).json()
            done = wait_state(c, job["id"], {"planned", "failed"}, timeout=60)
            assert done["state"] == "planned" and done["result"]["iterations"] > 0
            # kill -9 of the worker machine's process mid-job: a new worker recovers the job
            long = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-2"}}).json()
            wait_state(c, long["id"], {"planning"}, timeout=30)
            os.killpg(worker.pid, signal.SIGKILL)
            worker.wait(10)
            worker = _worker(pg_url)
            final = wait_state(c, long["id"], {"planned", "failed"}, timeout=60)
            assert final["state"] == "planned" and final["attempts"] == 2
    finally:
        if worker.poll() is None:
            worker.send_signal(signal.SIGTERM)
            try:
                worker.wait(10)
            except subprocess.TimeoutExpired:
                worker.kill()
        try:
            os.killpg(worker.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        api.stop()
