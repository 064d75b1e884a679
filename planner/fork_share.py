"""Share a short list of independent jobs between this process and one forked child.

Both take the next unclaimed job in turn (a shared counter), so a long job on one side does not
leave the other idle behind a fixed split. The child sends its results back in one message when
it runs out of jobs; this process keeps its own. Used for the motions of a candidate path
(:meth:`planner.regrasp_planner.HandConfigPlanner._prefetch_hops`), which are independent once
its key poses are valid.
"""

from __future__ import annotations

import traceback
from typing import Any, Callable, Sequence

from .forking import pool_context
from .regrasp_graph import Canceled

#: How often this process looks at ``should_stop`` while it waits for the child (seconds).
POLL_S = 0.02


def share_with_child(jobs: Sequence[Any], work: Callable[[Any, bool], Any],
                     should_stop: Callable[[], bool]) -> tuple[dict[int, Any], str | None]:
    """Run ``work(job, in_child)`` once per job, split between this process and a forked child.

    Returns every job's result by index, and the child's error (a traceback) if it failed: its
    unfinished jobs are then missing, for the caller to run itself. ``work`` raising here (a
    cancel) ends the child too. Call only where :func:`planner.forking.fork_is_safe`.
    """
    ctx = pool_context()
    if ctx.get_start_method() != "fork":
        raise RuntimeError("share_with_child needs fork (a single-threaded POSIX process)")
    claimed = ctx.Value("i", 0)
    receive, send = ctx.Pipe(duplex=False)

    def claim() -> int | None:
        with claimed.get_lock():
            k = claimed.value
            if k >= len(jobs):
                return None
            claimed.value = k + 1
            return k

    def child() -> None:
        done: dict[int, Any] = {}
        try:
            while (k := claim()) is not None:
                done[k] = work(jobs[k], True)
            send.send((done, None))
        except BaseException:
            send.send((done, traceback.format_exc()))

    proc = ctx.Process(target=child, name="regrasp-hops", daemon=True)
    proc.start()
    send.close()
    results: dict[int, Any] = {}
    try:
        while (k := claim()) is not None:
            results[k] = work(jobs[k], False)
        while not receive.poll(POLL_S):
            if should_stop():
                raise Canceled()
            if not proc.is_alive() and not receive.poll(0):
                return results, f"the helper process ended with exit code {proc.exitcode} and sent nothing"
        theirs, error = receive.recv()
        results.update(theirs)
        return results, error
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join(timeout=1.0)
        receive.close()
