"""Share a short list of independent jobs between this process and one forked child.

Both take the next unclaimed job in turn (a shared counter), so a long job on one side does not
leave the other idle behind a fixed split. The child sends each result back as soon as it has it;
this process keeps its own, and while it waits for the child's last ones it may work on what the
results so far allow (``idle``). Used for the motions of a candidate path
(:meth:`planner.regrasp.hand_config_planner.HandConfigPlanner._prefetch_hops`), which are independent once
its key poses are valid, and for the quicker paths of a plan's motions
(:meth:`planner.regrasp.plan_timing.PlanTimer.alternatives`), whose runs can be timed as their paths come in.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import queue
import signal
import threading
import traceback
from typing import Any, Callable, Sequence

from planner.regrasp.graph import Canceled

#: How often this process looks at ``should_stop`` while it waits for the child (seconds).
POLL_S = 0.02


def share_with_child(jobs: Sequence[Any], work: Callable[[Any, bool], Any],
                     should_stop: Callable[[], bool],
                     idle: Callable[[dict[int, Any]], bool] | None = None) -> tuple[dict[int, Any], str | None]:
    """Run ``work(job, in_child)`` once per job, split between this process and a forked child.

    Returns every job's result by index, and the child's error (a traceback) if it failed: its
    unfinished jobs are then missing, for the caller to run itself. ``work`` raising here (a
    cancel) ends the child too. ``idle(results)``, when given, is called with the results so far
    (by index) while this process has no job left and the child's next result has not come: it
    does one piece of the caller's own work that those results allow and says whether it did any
    (False: this process waits). Call only where :func:`planner.forking.fork_is_safe`. A bare
    ``os.fork`` (not a multiprocessing process): a service's worker is a daemonic process, which
    multiprocessing does not let have children.
    """
    ctx = mp.get_context("fork")
    claimed = ctx.Value("i", 0)
    receive, send = ctx.Pipe(duplex=False)

    def claim() -> int | None:
        with claimed.get_lock():
            k = claimed.value
            if k >= len(jobs):
                return None
            claimed.value = k + 1
            return k

    pid = os.fork()
    if pid == 0:  # the child: never returns into the caller's code
        code = 0
        try:
            receive.close()
            # Each result is pickled here and written by a thread: the caller reads only once its own jobs are
            # done, and a result larger than the pipe holds would otherwise stop this process's next job until then.
            outbox: queue.SimpleQueue = queue.SimpleQueue()
            writer = threading.Thread(target=_write_all, args=(outbox, send))
            writer.start()
            try:
                while (k := claim()) is not None:
                    outbox.put(pickle.dumps((k, work(jobs[k], True)), pickle.HIGHEST_PROTOCOL))
                outbox.put(pickle.dumps((None, None)))
            except BaseException:
                outbox.put(pickle.dumps((None, traceback.format_exc())))
            outbox.put(None)
            writer.join()
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    send.close()
    reaped, status = False, 0
    results: dict[int, Any] = {}
    try:
        while (k := claim()) is not None:
            results[k] = work(jobs[k], False)
        while True:
            if receive.poll(0):
                k, result = receive.recv()
                if k is None:  # the child's last message: done, or its error
                    return results, result
                results[k] = result
                continue
            if should_stop():
                raise Canceled()
            if idle is not None and idle(results):
                continue
            if reaped:  # ended, and everything it sent has been read
                return results, f"the helper process ended with status {status} and sent nothing more"
            if receive.poll(POLL_S):
                continue
            ended, status = os.waitpid(pid, os.WNOHANG)
            reaped = bool(ended)  # what it sent before it ended is read first
    finally:
        if not reaped:
            os.kill(pid, signal.SIGKILL)  # a zombie until reaped: the pid cannot have been reused
            os.waitpid(pid, 0)
        receive.close()


def _write_all(outbox: queue.SimpleQueue, send) -> None:
    """Write the pickled messages of ``outbox`` to the pipe, in order, until a None (the child's own thread)."""
    while (data := outbox.get()) is not None:
        send.send_bytes(data)
