"""The job store's check at start: a missing store is created, a damaged one is refused.

``regrasp serve`` and ``regrasp worker`` call :func:`check_store` before they open the
store. An embedded SQLite file is

- created when it does not exist (and the log says so);
- refused when it exists but is empty (zero bytes), is not an SQLite database, is shorter
  than its own header says (truncated), fails SQLite's ``quick_check`` (damaged pages), or
  holds tables but not those of a job store;
- with ``init=True`` (``--init-store``), moved aside (``jobs.sqlite.damaged-TIMESTAMP``, with
  its ``-wal`` and ``-shm`` files) and replaced by a new store: nothing is deleted.

A PostgreSQL store is checked by connecting to it. Every refusal is a
:class:`StoreIntegrityError` whose message says what is wrong and what to do.
"""

from __future__ import annotations

import logging
import sqlite3
import struct
from datetime import datetime, timezone
from pathlib import Path

import sqlalchemy as sa

from service.errors import RegraspServiceError

from .db import STORE_LOCK_TIMEOUT_S, StoreLockTimeout, make_engine, sqlite_store_lock, upgrade_schema as _upgrade

log = logging.getLogger("regrasp.store")

SQLITE_MAGIC = b"SQLite format 3\x00"
#: Tables whose presence marks an existing file as a job store (created by the migrations).
STORE_TABLES = frozenset({"alembic_version", "jobs"})


class StoreIntegrityError(RegraspServiceError):
    """The job store cannot be used as it is; the message says why and what to do."""


def check_store(url: str, *, init: bool = False, lock_timeout_s: float = STORE_LOCK_TIMEOUT_S) -> str:
    """Check the store at ``url`` before use; returns what was found (for the log), raises if unusable."""
    if url.startswith("sqlite"):
        path = sa.engine.make_url(url).database
        if not path or path == ":memory:":
            return "in-memory SQLite store"
        return check_sqlite_file(Path(path), init=init, lock_timeout_s=lock_timeout_s)
    return _check_server(url)


def check_sqlite_file(path: Path, *, init: bool = False, lock_timeout_s: float = STORE_LOCK_TIMEOUT_S) -> str:
    """Check (and, when missing, create) an SQLite store under the store lock: a process starting together with
    another never reads the file while the other is still making it."""
    try:
        with sqlite_store_lock(path, lock_timeout_s):
            return _check_sqlite_file(path, init=init)
    except StoreLockTimeout as exc:
        raise StoreIntegrityError(str(exc)) from None


def _check_sqlite_file(path: Path, *, init: bool) -> str:
    if not path.exists():
        log.warning("job store %s does not exist: creating a new, empty store", path)
        _create(path)
        return f"created a new job store at {path}"
    problem = sqlite_problem(path)
    if problem is None:
        return f"job store {path} passed its integrity check"
    if not init:
        raise StoreIntegrityError(
            f"the job store {path} {problem}; refusing to start on it. Restore it from a backup, or start with "
            f"--init-store to move it aside and begin a new, empty store")
    aside = path.with_name(f"{path.name}.damaged-{datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')}")
    for suffix in ("", "-wal", "-shm"):
        part = Path(str(path) + suffix)
        if part.exists():
            part.rename(Path(str(aside) + suffix))
    log.warning("job store %s %s: moved aside to %s (--init-store); creating a new, empty store", path, problem, aside)
    _create(path)
    return f"moved the damaged store aside to {aside} and created a new one"


def _create(path: Path) -> None:
    """A new store at ``path``, migrated whole (the caller holds the store lock, so no other process sees it half
    made)."""
    engine = make_engine(f"sqlite:///{path}", pool_size=1)
    try:
        _upgrade(engine)
    finally:
        engine.dispose()


def sqlite_problem(path: Path) -> str | None:
    """What is wrong with an existing SQLite store file, or None when it is sound."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            header = f.read(100)
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if size == 0:
        return "is an empty file (zero bytes), not a job store"
    if len(header) < 100 or not header.startswith(SQLITE_MAGIC):
        return "is not an SQLite database (its header is wrong)"
    page_size = struct.unpack(">H", header[16:18])[0]
    page_size = 65536 if page_size == 1 else page_size
    pages, change_counter, valid_for = struct.unpack(">I", header[28:32])[0], header[24:28], header[92:96]
    if page_size < 512 or page_size & (page_size - 1):
        return f"has a damaged header (page size {page_size})"
    wal = Path(str(path) + "-wal")
    if change_counter == valid_for and pages and pages * page_size > size and not (wal.exists() and wal.stat().st_size):
        return f"is truncated ({size} bytes; its header says {pages * page_size})"
    try:
        conn = sqlite3.connect(f"file:{path}?mode=rw", uri=True, timeout=10)
        try:
            rows = [r[0] for r in conn.execute("PRAGMA quick_check(5)").fetchall()]
            tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            conn.close()
    except sqlite3.DatabaseError as exc:
        return f"is damaged ({str(exc)[:200]})"
    if rows != ["ok"]:
        found = "; ".join(" ".join(str(r).split()) for r in rows if "in database" not in str(r))
        return f"is damaged (SQLite's integrity check: {found[:300]})"
    if tables and not STORE_TABLES <= tables:
        return f"is an SQLite database but not a job store (tables: {', '.join(sorted(tables))[:200]})"
    return None


def _check_server(url: str) -> str:
    engine = make_engine(url, pool_size=1)
    try:
        with engine.connect() as conn:
            conn.execute(sa.text("SELECT 1"))
    except sa.exc.DBAPIError as exc:
        first = str(exc.orig if exc.orig is not None else exc).strip().splitlines()
        raise StoreIntegrityError(f"cannot open the job store at {engine.url.render_as_string(hide_password=True)}: "
                                  f"{first[0][:300] if first else 'connection failed'}") from None
    finally:
        engine.dispose()
    return f"job store {engine.url.render_as_string(hide_password=True)} is reachable"
