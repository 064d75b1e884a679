"""The job store is checked when it opens; store errors while serving answer 503 problems.

`regrasp serve` and `regrasp worker` run as real processes on damaged SQLite files (zero
bytes, 64 KiB of random bytes inside a real store, a truncated store): each refuses with one
line and exit code 3, without a traceback, unless `--init-store` is given, which moves the
file aside (never deletes it) and starts a new store. A missing store is created and the log
says so.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import httpx
import pytest
from conftest import ROOT, Server, free_port, service_env

from service.store import JobStore, make_engine, migrate

#: Exit code of a damaged or unreachable store (service.cli.common.EXIT_STORE).
EXIT_STORE = 3
#: A refusal comes before the server binds; imports alone take seconds on a loaded machine.
REFUSE_TIMEOUT_S = 120


def _real_store(path: Path, jobs: int = 300) -> None:
    """A job store with enough rows to span many pages."""
    engine = make_engine(f"sqlite:///{path}")
    migrate(engine)
    store = JobStore(engine)
    for i in range(jobs):
        store.create(job_id=f"job-{i:04d}", kind="plan", submitter="alice", request={"scenario": "upright", "pad": "x" * 400},
                     request_sha256=f"{i:064d}", idempotency_key=None, provenance={})
    engine.dispose()
    for suffix in ("-wal", "-shm"):
        assert not Path(str(path) + suffix).exists() or suffix == "-shm" or Path(str(path) + suffix).stat().st_size == 0


def _zero_length(path: Path) -> None:
    path.write_bytes(b"")


def _random_inside(path: Path) -> None:
    _real_store(path)
    with open(path, "r+b") as f:
        f.seek(8192)
        f.write(os.urandom(64 * 1024))


def _truncated(path: Path) -> None:
    _real_store(path)
    size = path.stat().st_size
    with open(path, "r+b") as f:
        f.truncate(size // 2)


def _run(command: str, data_dir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "service.cli.main", command, "--data-dir", str(data_dir), *args]
    if command == "serve":
        argv += ["--workers", "0", "--port", str(free_port())]
    else:
        argv += ["--workers", "1"]
    return subprocess.run(argv, cwd=ROOT, env=service_env(), capture_output=True, text=True, timeout=REFUSE_TIMEOUT_S)


@pytest.mark.parametrize("damage, said", [(_zero_length, "empty file"), (_random_inside, "damaged"),
                                          (_truncated, "truncated")], ids=["zero-length", "random-bytes", "truncated"])
def test_serve_refuses_a_damaged_store_with_one_line_and_exit_3(tmp_path: Path, damage: Callable[[Path], None],
                                                               said: str) -> None:
    store = tmp_path / "jobs.sqlite"
    damage(store)
    before = store.read_bytes()
    done = _run("serve", tmp_path)
    out = done.stdout + done.stderr
    assert done.returncode == EXIT_STORE, out[-2000:]
    assert "Traceback" not in out
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and said in errors[0] and "--init-store" in errors[0], out[-2000:]
    assert store.read_bytes() == before  # refused, untouched


def test_worker_refuses_a_damaged_store_too(tmp_path: Path) -> None:
    _zero_length(tmp_path / "jobs.sqlite")
    done = _run("worker", tmp_path)
    assert done.returncode == EXIT_STORE and "Traceback" not in done.stderr + done.stdout
    assert "empty file" in done.stderr + done.stdout


def test_init_store_moves_the_damaged_file_aside_and_starts_a_new_store(tmp_path: Path) -> None:
    _random_inside(tmp_path / "jobs.sqlite")
    damaged = (tmp_path / "jobs.sqlite").read_bytes()
    srv = Server(tmp_path, workers=0, extra_args=["--init-store", "--log-level", "info"]).start()
    try:
        with srv.client("alice") as c:
            assert c.get("/v1/jobs").json()["total"] == 0
            assert c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}}).status_code == 202
    finally:
        srv.stop()
    aside = list(tmp_path.glob("jobs.sqlite.damaged-*"))
    assert len(aside) == 1 and aside[0].read_bytes() == damaged
    assert "moved aside" in srv.log_path.read_text()


def test_a_missing_store_is_created_and_the_log_says_so(tmp_path: Path) -> None:
    data_dir = tmp_path / "new"
    srv = Server(data_dir, workers=0).start()
    try:
        assert httpx.get(srv.url + "/healthz").json()["database"] == "sqlite"
    finally:
        srv.stop()
    assert (data_dir / "jobs.sqlite").is_file()
    assert "does not exist: creating a new, empty store" in srv.log_path.read_text()


def test_a_sound_store_passes_and_keeps_its_jobs(tmp_path: Path) -> None:
    _real_store(tmp_path / "jobs.sqlite", jobs=3)
    srv = Server(tmp_path, workers=0).start()
    try:
        with srv.client("alice") as c:
            assert c.get("/v1/jobs").json()["total"] == 3
    finally:
        srv.stop()


def test_store_errors_while_serving_answer_503_problems(tmp_path: Path) -> None:
    """The store's file goes away under a running app: every route that reads it answers 503, not 500."""
    import sqlalchemy as sa
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.api.auth import TokenStore
    from service.execution.bridge import NoBridge
    from service.settings import ServiceSettings

    settings = ServiceSettings(data_dir=tmp_path, workers=0, audit=False)
    tokens = TokenStore.from_plain({"tok-alice-planner": {"user": "alice", "roles": ["planner"]}})
    app = create_app(settings, tokens=tokens, run_workers=False, bridge=NoBridge())
    headers = {"Authorization": "Bearer tok-alice-planner"}
    with TestClient(app, raise_server_exceptions=False) as c:
        assert c.get("/v1/jobs", headers=headers).status_code == 200
        svc = app.state.service
        svc.store.engine = sa.create_engine(f"sqlite:///{tmp_path / 'gone' / 'jobs.sqlite'}")  # cannot be opened
        answers = [c.get("/v1/jobs", headers=headers), c.get("/v1/jobs/some-id", headers=headers),
                   c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "upright"}}, headers=headers),
                   c.get("/healthz")]
    for r in answers:
        assert r.status_code == 503, (r.status_code, r.text)
        assert r.headers["content-type"].startswith("application/problem+json")
        assert "job store" in r.json()["detail"] and "Error" not in r.json()["detail"]
        assert int(r.headers["retry-after"]) >= 1



#: What `regrasp serve` and `regrasp worker` do at start: check the store, then migrate it. Every process imports
#: first, then says it is ready and waits for the others (a barrier of files), so their checks and migrations overlap.
_OPEN_NEW_STORE = """
import pathlib, sys, time
from service.store import make_engine, migrate
from service.store.integrity import StoreIntegrityError, check_store
path, barrier, me, count = sys.argv[1], pathlib.Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])
(barrier / me).touch()
deadline = time.monotonic() + 90
while len(list(barrier.iterdir())) < count and time.monotonic() < deadline:
    time.sleep(0.001)
try:
    check_store(f"sqlite:///{path}")
except StoreIntegrityError as exc:
    print(f"refused: {exc}")
    sys.exit(0)
engine = make_engine(f"sqlite:///{path}")
migrate(engine)
engine.dispose()
print("ok")
"""


def test_processes_starting_together_on_a_new_store_all_open_it(tmp_path: Path) -> None:
    """An API replica and its workers started at once (as docker compose does) on a store that does not exist
    yet: none sees the store half made (an empty file, or tables of an unfinished migration) and refuses it,
    and none fails migrating it."""
    processes = 4
    env = service_env()
    for attempt in range(4):
        path = tmp_path / f"store-{attempt}" / "jobs.sqlite"
        barrier = tmp_path / f"ready-{attempt}"
        barrier.mkdir()
        procs = [subprocess.Popen([sys.executable, "-c", _OPEN_NEW_STORE, str(path), str(barrier), str(i),
                                   str(processes)], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
                 for i in range(processes)]
        outcomes = []
        for proc in procs:
            out, err = proc.communicate(timeout=120)
            outcomes.append(out.strip() if proc.returncode == 0 else f"exit {proc.returncode}: {err[-600:]}")
        assert outcomes == ["ok"] * processes, (attempt, outcomes)
        engine = make_engine(f"sqlite:///{path}")
        JobStore(engine).create(job_id="j", kind="plan", submitter="alice", request={}, request_sha256="0" * 64,
                                idempotency_key=None, provenance={})
        engine.dispose()
        assert sorted(p.name for p in path.parent.iterdir() if not p.name.endswith(("-wal", "-shm"))) == ["jobs.sqlite"]


def test_a_process_that_holds_the_store_lock_too_long_is_named_not_waited_for_forever(tmp_path: Path) -> None:
    """A server or worker stuck while creating or migrating the store (here: the lock taken and kept) makes the
    next one's start fail after the bounded wait, saying what it waited for; once the lock is free the store opens."""
    import fcntl

    from service.store.integrity import StoreIntegrityError, check_store

    path = tmp_path / "store" / "jobs.sqlite"
    path.parent.mkdir()
    holder = os.open(path.parent, os.O_RDONLY)
    try:
        fcntl.flock(holder, fcntl.LOCK_EX)
        started = time.monotonic()
        with pytest.raises(StoreIntegrityError, match="held the lock of the job store .* for over 0.5 s"):
            check_store(f"sqlite:///{path}", lock_timeout_s=0.5)
        assert 0.5 <= time.monotonic() - started < 30.0
        assert not path.exists()  # nothing was made while another process held the lock
    finally:
        os.close(holder)
    assert "created a new job store" in check_store(f"sqlite:///{path}", lock_timeout_s=0.5)
