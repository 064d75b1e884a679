"""Who owns claimed jobs: owner ids, and the owners alive in this process.

A runner and the dispatch executions claim jobs under an owner id (host, pid and a nonce: pids
are reused). When a job's lease runs out, recovery asks whether its owner is dead: on this host
an owner whose process is gone is, and one with this process's pid is dead unless it is still
registered here (a runner stopped in this process, or one from before a fork).
"""

from __future__ import annotations

import os
import threading
import uuid

from ..store.repo import this_host


def make_owner_id() -> str:
    """Unique id of a runner: host, pid and a nonce (pids are reused)."""
    return f"{this_host()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


class LiveOwners:
    """The owner ids alive in this process; shared by the service's runner and its executions."""

    def __init__(self) -> None:
        self._ids: set[str] = set()
        self._lock = threading.Lock()

    def add(self, owner: str) -> None:
        with self._lock:
            self._ids.add(owner)

    def discard(self, owner: str) -> None:
        with self._lock:
            self._ids.discard(owner)

    def __contains__(self, owner: object) -> bool:
        with self._lock:
            return owner in self._ids

    def is_dead(self, owner: str) -> bool:
        """True if the owner ran on this host and is gone (other hosts: rely on the lease)."""
        host, _, rest = owner.partition(":")
        pid_text = rest.partition(":")[0]
        if host != this_host() or not pid_text.isdigit():
            return False
        pid = int(pid_text)
        if pid == os.getpid():
            return owner not in self
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False
        return False
