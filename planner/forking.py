"""When the planner may fork helper processes.

A forked child starts with the parent's imported modules and built task, so it costs
milliseconds where a spawned one costs ~2 s of imports and set-up. It is safe only from a
single-threaded process: threads do not survive a fork, and a copy of a lock another thread
held deadlocks the child. The CLI and the benchmarks are single-threaded (the progress bar is
redrawn by the callback); a multi-threaded host gets spawned pools, or no helper at all.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading


def fork_is_safe() -> bool:
    """POSIX fork is available and this process runs one thread."""
    return "fork" in mp.get_all_start_methods() and threading.active_count() == 1


def pool_context():
    """``fork`` where :func:`fork_is_safe`, ``spawn`` otherwise."""
    return mp.get_context("fork" if fork_is_safe() else "spawn")


def spare_cores() -> int:
    """Cores beyond the one this process runs on."""
    return max((os.cpu_count() or 1) - 1, 0)
