"""Process-wide tuning for the processes that carry bridge traffic (the controller, the service)."""

from __future__ import annotations

import gc


def freeze_startup_objects() -> None:
    """Move what exists now (modules, schemas, settings, sessions: it lives as long as the process) out of
    the garbage collector's reach. A full collection over it stops every thread, zenoh callbacks and the
    dispatcher's sends included: 20-40 ms in the controller (~40k objects), ~67 ms in the service (~113k)."""
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

    Only for threads that sleep between short pieces of work (the bridge's): the kernel's real-time
    throttling (95 % of each second by default) is the safety net should one ever spin."""
    import os
    import threading

    if priority is None or not hasattr(os, "sched_setscheduler"):
        return False
    try:
        os.sched_setscheduler(threading.get_native_id(), os.SCHED_RR, os.sched_param(priority))
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
