"""Process-wide tuning for the processes that carry bridge traffic (the controller, the service)."""

from __future__ import annotations

import gc
from contextlib import contextmanager
from typing import Any, Iterator


def freeze_startup_objects() -> None:
    """Move what exists now (modules, schemas, settings, sessions: it lives as long as the process) out of
    the garbage collector's reach. A full collection over it stops every thread, zenoh callbacks and the
    dispatcher's sends included, for tens of milliseconds when the objects number in the tens of thousands."""
    gc.collect()
    gc.freeze()


#: Python's thread switch interval in a process that carries bridge traffic beside other Python work (the
#: service): a zenoh callback or the heartbeat thread waits about this long for the interpreter (default 5 ms).
BRIDGE_SWITCH_INTERVAL_S = 0.0005


def shorten_switch_interval(interval_s: float = BRIDGE_SWITCH_INTERVAL_S) -> None:
    """Let the bridge's threads in at most every ``interval_s`` when other threads run Python."""
    import sys

    if sys.getswitchinterval() > interval_s:
        sys.setswitchinterval(interval_s)


def use_realtime_scheduling(priority: int | None) -> bool:
    """Run the calling thread (and the threads it starts from now on, which inherit it) under SCHED_RR at
    ``priority`` (1-99): it then preempts every ordinary process, however busy the cores are. Needs
    CAP_SYS_NICE; without it nothing changes and False is returned. None leaves the policy alone.

    The policy carries SCHED_RESET_ON_FORK: a process started from such a thread (a competitor a benchmark
    spawns, a subprocess of the service) begins at ordinary priority, never real-time.

    Only for threads that sleep between short pieces of work (the bridge's): the kernel's real-time
    throttling (95 % of each second by default) is the safety net should one ever spin."""
    import os
    import threading

    if priority is None or not hasattr(os, "sched_setscheduler"):
        return False
    try:
        policy = os.SCHED_RR | getattr(os, "SCHED_RESET_ON_FORK", 0)
        os.sched_setscheduler(threading.get_native_id(), policy, os.sched_param(priority))
    except (PermissionError, OSError):
        return False
    return True


def raise_thread_priority(nice: int | None) -> bool:
    """Give the calling thread (and the threads it starts from now on, which inherit it) niceness ``nice``.

    Linux keeps a niceness per thread, so only the threads on the bridge's path are raised, not a whole
    service. A value below the current one needs CAP_SYS_NICE: without it nothing changes and False is
    returned (the bridge still runs, at normal priority). None leaves the priority alone."""
    import os
    import threading

    if nice is None or not hasattr(os, "setpriority"):
        return False
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
    except (PermissionError, OSError):
        return False
    return True


@contextmanager
def bridge_priority(nice: int | None, realtime: int | None) -> Iterator[None]:
    """Run the calling thread at the bridge's priority for the block (SCHED_RR at ``realtime`` where allowed,
    niceness ``nice``), then give it its own back. Threads started in the block keep the bridge's priority.

    For a thread of an ordinary process that carries bridge traffic for a while (an execution loop, the
    opening of a zenoh session whose runtime threads inherit it): every thread that takes the interpreter
    lock on the bridge's path must be as urgent as the heartbeat's, or a busy core deschedules it while it
    holds the lock and the heartbeat waits behind it."""
    import os
    import threading

    tid = threading.get_native_id()
    try:
        before_nice: int | None = os.getpriority(os.PRIO_PROCESS, tid)
    except (AttributeError, OSError):
        before_nice = None
    try:
        before_sched: tuple[int, Any] | None = (os.sched_getscheduler(tid), os.sched_getparam(tid))
    except (AttributeError, OSError):
        before_sched = None
    raise_thread_priority(nice)
    use_realtime_scheduling(realtime)
    try:
        yield
    finally:
        if before_sched is not None:
            try:
                os.sched_setscheduler(tid, *before_sched)
            except (PermissionError, OSError):
                pass
        if before_nice is not None:
            raise_thread_priority(before_nice)


#: A CPU-bound process for benchmarks and tests that load the machine: it first puts itself at ordinary
#: priority (SCHED_OTHER, niceness 0), whatever the thread that started it ran at, so it competes like any
#: other program and never starves the machine.
_COMPETITOR_CODE = (
    "import os\n"
    "try:\n"
    "    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))\n"
    "    os.setpriority(os.PRIO_PROCESS, 0, 0)\n"
    "except OSError:\n"
    "    pass\n"
    "while True:\n"
    "    pass\n"
)


def cpu_competitor_command() -> list[str]:
    """The command line of one CPU-bound competitor at ordinary priority (see ``_COMPETITOR_CODE``)."""
    import sys

    return [sys.executable, "-c", _COMPETITOR_CODE]
