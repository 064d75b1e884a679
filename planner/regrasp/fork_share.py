"""Share a short list of independent jobs between this process and one forked child.

Both take the next unclaimed job in turn (a shared counter), so a long job on one side does not
leave the other idle behind a fixed split. The child sends its results back in one message when it
runs out of jobs, or, where this process has work of its own to do with them (``idle``), each as soon
as it has it; this process keeps its own. Used for the motions of a candidate path
(:meth:`planner.regrasp.hand_config_planner.HandConfigPlanner._prefetch_hops`), which are independent once
its key poses are valid, and for the quicker paths of a plan's motions
(:meth:`planner.regrasp.timing.quicker_paths.QuickerPaths.alternatives`), whose runs can be timed as their paths come in.
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
    (False: this process waits); the child then sends each result as it is found. Call only where :func:`planner.forking.fork_is_safe`. A bare
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
            _child(claim, jobs, work, send, stream=idle is not None)
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
                theirs, finished, error = receive.recv()
                results.update(theirs)
                if finished:  # the child's last message: done, or its error
                    return results, error
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


def _child(claim: Callable[[], int | None], jobs: Sequence[Any], work: Callable[[Any, bool], Any], send,
           stream: bool) -> None:
    """The child's side: claim and work jobs until none is left, and send the results as messages
    ``(results by index, finished, error)``. Without ``stream``, one message at the end (the caller has nothing to
    do with a part of them). With it, one per result as it is found and an empty last one, each pickled here and
    written by a thread of the child: the caller reads only once its own jobs are done, and a result larger than
    the pipe holds (a hop's timed motion is 0.2-0.4 MB) would otherwise stop the child's next job until then."""
    done: dict[int, Any] = {}
    outbox: queue.SimpleQueue | None = queue.SimpleQueue() if stream else None
    writer = threading.Thread(target=_write_all, args=(outbox, send)) if outbox is not None else None
    if writer is not None:
        writer.start()
    error = None
    try:
        while (k := claim()) is not None:
            result = work(jobs[k], True)
            if outbox is not None:
                outbox.put(pickle.dumps(({k: result}, False, None), pickle.HIGHEST_PROTOCOL))
            else:
                done[k] = result
    except BaseException:
        error = traceback.format_exc()
    if outbox is None:
        send.send((done, True, error))
        return
    outbox.put(pickle.dumps((done, True, error), pickle.HIGHEST_PROTOCOL))
    outbox.put(None)
    writer.join()


def _write_all(outbox: queue.SimpleQueue, send) -> None:
    """Write the pickled messages of ``outbox`` to the pipe, in order, until a None (the child's writer thread)."""
    while (data := outbox.get()) is not None:
        send.send_bytes(data)
