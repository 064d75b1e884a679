"""Share a short list of independent jobs between this process and one forked child.

Both take the next unclaimed job in turn (a shared counter), so a long job on one side does not
leave the other idle behind a fixed split. The child sends its results back in one message when
it runs out of jobs; this process keeps its own. Used for the motions of a candidate path
(:meth:`planner.regrasp.hand_config_planner.HandConfigPlanner._prefetch_hops`), which are independent once
its key poses are valid.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import traceback
from typing import Any, Callable, Sequence

from planner.regrasp.graph import Canceled

#: How often this process looks at ``should_stop`` while it waits for the child (seconds).
POLL_S = 0.02


def share_with_child(jobs: Sequence[Any], work: Callable[[Any, bool], Any],
                     should_stop: Callable[[], bool]) -> tuple[dict[int, Any], str | None]:
    """Run ``work(job, in_child)`` once per job, split between this process and a forked child.

    Returns every job's result by index, and the child's error (a traceback) if it failed: its
    unfinished jobs are then missing, for the caller to run itself. ``work`` raising here (a
    cancel) ends the child too. Call only where :func:`planner.forking.fork_is_safe`. A bare
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
            done: dict[int, Any] = {}
            try:
                while (k := claim()) is not None:
                    done[k] = work(jobs[k], True)
                send.send((done, None))
            except BaseException:
                send.send((done, traceback.format_exc()))
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    send.close()
    reaped = False
    results: dict[int, Any] = {}
    try:
        while (k := claim()) is not None:
            results[k] = work(jobs[k], False)
        while not receive.poll(POLL_S):
            if should_stop():
                raise Canceled()
            ended, status = os.waitpid(pid, os.WNOHANG)
            if ended:
                reaped = True
                if not receive.poll(0):
                    return results, f"the helper process ended with status {status} and sent nothing"
        theirs, error = receive.recv()
        results.update(theirs)
        return results, error
    finally:
        if not reaped:
            os.kill(pid, signal.SIGKILL)  # a zombie until reaped: the pid cannot have been reused
            os.waitpid(pid, 0)
        receive.close()
