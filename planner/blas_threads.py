"""One BLAS thread for the planner's own work.

The planner runs in parallel across processes, never threads: forked helpers share a plan's search hops, quicker
paths and run timings; a survey's seeds run in worker processes or Ray tasks, one per core. Each does small matrix
products (TOPP-RA's constraint set-up, the timing's rows, the state checks). With its default thread pool, OpenBLAS
splits such a product over every core and its threads then wait by spinning, so a helper and its parent each take
the other's core. One thread per process is what that parallelism assumes.

It also keeps a plan independent of the machine's core count: the last bits of a product can change with the
number of threads OpenBLAS splits it over, and through them a search's or a timing's choices followed the cores.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import TypeVar

from threadpoolctl import ThreadpoolController

F = TypeVar("F", bound=Callable)


def one_thread(libraries: ThreadpoolController | None = None) -> AbstractContextManager:
    """A context holding the BLAS libraries to one thread, the previous limit restored at its end. ``libraries``: the
    loaded libraries found once (a ``ThreadpoolController``), for a caller that enters it often; by default they are
    looked up on entry, which takes about a millisecond."""
    return (libraries or ThreadpoolController()).limit(limits=1, user_api="blas")


def one_blas_thread(fn: F) -> F:
    """``fn`` run in :func:`one_thread` (a forked child inherits the limit; a spawned process or a Ray worker is held
    again by the function it runs)."""

    @functools.wraps(fn)
    def held(*args, **kwargs):
        with one_thread():
            return fn(*args, **kwargs)

    return held  # type: ignore[return-value]
