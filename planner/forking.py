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

#: The attribute that marks a thread declared lock-free (:func:`declare_fork_benign`). The mark is kept on
#: the thread itself, so it goes when the thread goes and no module keeps a registry of threads.
_BENIGN_MARK = "_regrasp_fork_benign"


def declare_fork_benign(thread: threading.Thread) -> None:
    """Declare a thread that only sleeps and makes system calls (no locks, no allocation while another
    thread forks), such as a service worker's parent watch: it does not make forking unsafe."""
    setattr(thread, _BENIGN_MARK, True)


def fork_is_safe() -> bool:
    """POSIX fork is available and this process runs one thread, besides threads declared benign."""
    if "fork" not in mp.get_all_start_methods():
        return False
    others = [t for t in threading.enumerate() if t is not threading.current_thread()]
    return all(getattr(t, _BENIGN_MARK, False) for t in others)


def pool_may_fork() -> bool:
    """A forked multiprocessing pool may start here: :func:`fork_is_safe`, and this is not a daemonic
    process (multiprocessing lets those start no children; a service's workers are such)."""
    return fork_is_safe() and not mp.current_process().daemon


def pool_context():
    """``fork`` where :func:`fork_is_safe`, ``spawn`` otherwise."""
    return mp.get_context("fork" if fork_is_safe() else "spawn")


def spare_cores() -> int:
    """Cores beyond the one this process runs on."""
    return max((os.cpu_count() or 1) - 1, 0)


def helper_may_fork(asked: bool) -> bool:
    """Whether work may be shared with a forked helper: asked for (a task's ``parallel_motions``), a second core to
    run it (:func:`spare_cores`) and a process it is safe to fork (:func:`fork_is_safe`)."""
    return asked and spare_cores() > 0 and fork_is_safe()
