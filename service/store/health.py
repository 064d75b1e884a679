"""Whether the service can keep what it is given: room and writes in its data directory, and a store that writes.

A full or read-only disk, or a store whose writes fail, makes the service sick: ``/healthz`` answers 503
with the reason, submissions are refused with 503 and the reason, and the runner fails its running jobs
with the reason (it takes no new ones) instead of losing them in ``planning``. The reason names the disk.

The check is cheap (a ``statvfs`` and a one-byte probe file) and runs at most once per
``check_interval_s``; a write that failed anywhere (:meth:`StorageHealth.note_failure`) makes the service
sick at once. The service becomes healthy again when a later check finds room and writes working.
A small reserve file is kept in the data directory and given up when the disk fills, so that the jobs'
failures can still be written down.
"""

from __future__ import annotations

import errno
import logging
import os
import shutil
import threading
import time
from pathlib import Path

log = logging.getLogger("regrasp.storage")

#: Name of the reserve file in the data directory.
RESERVE_NAME = ".regrasp-reserve"
#: Name of the write probe in the data directory.
PROBE_NAME = ".regrasp-write-probe"

#: Errors of the operating system that mean "the disk will not take this" (not a bug of ours).
STORAGE_ERRNOS = {errno.ENOSPC: "full", errno.EDQUOT: "over its quota", errno.EROFS: "read-only",
                  errno.EIO: "failing (I/O error)", errno.EACCES: "not writable (permission denied)"}
#: What SQLite says when its file cannot be written.
STORE_MESSAGES = {"database or disk is full": "full", "readonly database": "read-only",
                  "disk i/o error": "failing (I/O error)", "unable to open database file": "not writable"}
#: The one SQLite message that may be the store's own fault rather than the disk's (see ``note_failure``).
UNOPENABLE = STORE_MESSAGES["unable to open database file"]


def storage_trouble(exc: BaseException) -> str | None:
    """How a failed write says the disk is sick (``"full"``, ``"read-only"``, ...), or None for any other error."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in STORAGE_ERRNOS:
            return STORAGE_ERRNOS[exc.errno]
        text = str(exc).lower()
        for needle, what in STORE_MESSAGES.items():
            if needle in text:
                return what
        exc = getattr(exc, "orig", None) or exc.__cause__ or exc.__context__  # type: ignore[assignment]
    return None


class StorageHealth:
    """The data directory's state: None while it takes writes, else the reason it does not (thread-safe)."""

    def __init__(self, data_dir: Path, *, min_free_bytes: int, reserve_bytes: int, check_interval_s: float = 1.0) -> None:
        self.data_dir = Path(data_dir)
        self.min_free_bytes = int(min_free_bytes)
        self.reserve_bytes = int(reserve_bytes)
        self.check_interval_s = float(check_interval_s)
        self._lock = threading.Lock()
        self._problem: str | None = None
        self._noted: str | None = None
        self._last_check = float("-inf")

    @property
    def problem(self) -> str | None:
        """Why the service cannot store data now, or None."""
        return self.check()

    def start(self) -> None:
        """Keep the reserve file (best effort) and take a first look."""
        self._make_reserve()
        self.check(force=True)

    def _make_reserve(self) -> None:
        path = self.data_dir / RESERVE_NAME
        if self.reserve_bytes <= 0 or (path.exists() and path.stat().st_size >= self.reserve_bytes):
            return
        try:
            with open(path, "wb") as fh:
                fh.write(b"\0" * self.reserve_bytes)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError:
            path.unlink(missing_ok=True)

    def release_reserve(self) -> bool:
        """Give up the reserve file so that failures can be recorded; True if there was one."""
        try:
            (self.data_dir / RESERVE_NAME).unlink()
            return True
        except OSError:
            return False

    def _look(self) -> str | None:
        where = str(self.data_dir)
        try:
            free = shutil.disk_usage(self.data_dir).free
        except OSError as exc:
            return f"the data directory {where} cannot be read ({exc.strerror or exc})"
        if free < self.min_free_bytes:
            return (f"the disk of the data directory {where} is full: {free / 1e6:.1f} MB free, "
                    f"the service needs {self.min_free_bytes / 1e6:.1f} MB")
        probe = self.data_dir / PROBE_NAME
        try:
            fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                os.write(fd, b"1")
                os.fsync(fd)
            finally:
                os.close(fd)
            probe.unlink()
        except OSError as exc:
            what = STORAGE_ERRNOS.get(exc.errno or 0, f"not writable ({exc.strerror or exc})")
            return f"the disk of the data directory {where} is {what}"
        return None

    def check(self, force: bool = False) -> str | None:
        """The reason the service cannot store data, looked at again when ``check_interval_s`` has passed."""
        now = time.monotonic()
        with self._lock:
            if not force and now - self._last_check < self.check_interval_s:
                return self._problem
            self._last_check = now
        found = self._look()
        with self._lock:
            if found is None and self._noted is not None and now - self._noted_at < self.check_interval_s * 5:
                found = self._noted  # a write failed a moment ago: the disk's own look is not enough yet
            elif found is None:
                self._noted = None
            was, self._problem = self._problem, found
        if found != was:
            if found is not None:
                log.error("storage: %s; submissions are refused and running jobs fail until it is fixed", found)
            else:
                log.warning("storage: the data directory takes writes again; the service is healthy")
                self._make_reserve()
        return found

    def note_failure(self, exc: BaseException, what: str) -> str | None:
        """A write failed; if the disk or store is why, the service is sick from now on: the reason, else None."""
        trouble = storage_trouble(exc)
        if trouble is None:
            return None
        if trouble == UNOPENABLE:
            # SQLite says the same of a missing or damaged store file as of a disk it cannot write: only the
            # disk's own look decides; a healthy disk leaves it the store's error.
            seen = self._look()
            if seen is None:
                return None
            reason = f"{seen} ({what} failed)"
        else:
            reason = f"the disk of the data directory {self.data_dir} is {trouble} ({what} failed)"
        with self._lock:
            self._noted, self._noted_at = reason, time.monotonic()
            was, self._problem = self._problem, self._problem or reason
        if was is None:
            log.error("storage: %s; submissions are refused and running jobs fail until it is fixed", reason)
        return self._problem

    _noted_at: float = 0.0
