"""Engine creation (SQLite WAL + busy timeout, or PostgreSQL) and Alembic migrations."""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from pathlib import Path
from typing import Iterator

import sqlalchemy as sa
from alembic import command
from alembic.config import Config

from service.errors import RegraspServiceError

#: How long an SQLite writer waits for the lock before failing, ms.
SQLITE_BUSY_TIMEOUT_MS = 10_000
MIGRATIONS_DIR = Path(__file__).parent / "migrations"
#: PostgreSQL advisory lock held while migrating (any constant unique to this application).
MIGRATION_LOCK_KEY = 0x5E6A5501
#: How long a process waits for another to finish creating or migrating an SQLite store, s.
STORE_LOCK_TIMEOUT_S = 60.0


class StoreLockTimeout(RegraspServiceError):
    """Another process held the store's lock (creating or migrating it) for longer than the wait allowed."""


def make_engine(url: str, *, pool_size: int = 10) -> sa.Engine:
    """An engine for the job store; SQLite files get WAL, a busy timeout and foreign keys."""
    if url.startswith("sqlite"):
        path = sa.engine.make_url(url).database
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        engine = sa.create_engine(
            url,
            connect_args={"check_same_thread": False, "timeout": SQLITE_BUSY_TIMEOUT_MS / 1000},
            pool_size=pool_size,
            max_overflow=2 * pool_size,
        )

        @sa.event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record) -> None:  # type: ignore[no-untyped-def]
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        return engine
    if url.startswith("postgresql://"):
        url = "postgresql+psycopg://" + url[len("postgresql://"):]
    return sa.create_engine(url, pool_size=pool_size, max_overflow=2 * pool_size, pool_pre_ping=True)


def alembic_config(engine: sa.Engine) -> Config:
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.attributes["engine"] = engine
    return cfg


@contextlib.contextmanager
def sqlite_store_lock(path: Path, timeout_s: float = STORE_LOCK_TIMEOUT_S) -> Iterator[None]:
    """Held while one process checks, creates or migrates an SQLite store file: API replicas and workers started
    together (as docker compose starts them) then never see a store half made, nor migrate it twice.

    It is an ``flock`` on the store's folder, not on the file: SQLite's own POSIX locks on the file would be
    dropped when any other descriptor of it closes, and the folder leaves no lock file behind. A process must
    not take it twice (two descriptors' flocks exclude each other). The wait is bounded: a process that holds the
    lock longer than ``timeout_s`` (hung or stopped while migrating) gets a :class:`StoreLockTimeout` that says so."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    raise StoreLockTimeout(
                        f"another process has held the lock of the job store {path} (on its folder) for over "
                        f"{timeout_s:g} s while creating or migrating it; is a server or worker stuck starting on "
                        f"the same store?") from None
                time.sleep(0.05)
        yield
    finally:
        os.close(fd)  # releases the flock


def sqlite_file(engine: sa.Engine) -> Path | None:
    """The file of an SQLite store, None for PostgreSQL or an in-memory store."""
    if engine.dialect.name != "sqlite":
        return None
    path = engine.url.database
    return Path(path) if path and path != ":memory:" else None


def migrate(engine: sa.Engine) -> None:
    """Bring the store's schema to the newest revision (idempotent, and safe when processes start together)."""
    path = sqlite_file(engine)
    with sqlite_store_lock(path) if path is not None else contextlib.nullcontext():
        upgrade_schema(engine)


def upgrade_schema(engine: sa.Engine) -> None:
    """The migration itself; an SQLite store's caller holds :func:`sqlite_store_lock`."""
    with engine.begin() as conn:
        if engine.dialect.name == "postgresql":
            # API replicas and workers may start together: one migrates, the others wait for it.
            conn.execute(sa.text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK_KEY})
        cfg = alembic_config(engine)
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")
