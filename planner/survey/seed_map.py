"""Where a survey's seeds run: a seed map runs a pure per-seed function on seeds, wherever it likes.

The estimator (:func:`planner.survey.estimator.run_rows`) decides which seeds to run and judges
their counts in seed order; a :class:`SeedMap` only runs ``fn(hands, seed, keep_states)`` on them
and hands back futures. The answer cannot depend on the map: each seed draws from its own
generator, and a row is judged on its first seeds in order. :class:`ForkedSeeds` runs seeds in
forked processes on this machine; the service's Ray seed map (``service.executors.ray_seeds``)
runs them as tasks across a cluster's nodes.
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any, Callable, Protocol

#: One seed's work: ``fn(hands, seed, keep_states)`` -> its counts (a ``planner.survey.estimator.SeedCount``);
#: pure (depends on its arguments only).
SeedFn = Callable[[str, int, bool], Any]

#: The per-seed function of this process when it is a forked seed worker: set once by its pool's
#: initializer, from the pool's own arguments (inherited through the fork, not pickled). A parent never
#: sets it, so two surveys in threads of one process each hand their pool its own function.
_WORKER_FN: SeedFn | None = None


def _start_seed_worker(fn: SeedFn) -> None:
    global _WORKER_FN
    _WORKER_FN = fn


class SeedSession(Protocol):
    """Seeds of one survey in flight."""

    def submit(self, hands: str, seed: int, keep_states: bool) -> Future:
        """Start one seed; the future's result is its :class:`SeedCount`."""

    def cancel(self, future: Future) -> None:
        """The seed's answer is no longer needed: stop it if it has not started (or can be stopped)."""

    def close(self, cancel: bool) -> None:
        """End the session; ``cancel`` stops every seed still running at once (the survey was cancelled)."""


class SeedMap(Protocol):
    """Runs a survey's seeds; ``slots`` is how many run at once."""

    slots: int

    def open(self, fn: SeedFn) -> SeedSession:
        """A session that runs ``fn`` on the seeds submitted to it."""


def _forked_seed(args: tuple) -> Any:
    hands, seed, keep = args
    assert _WORKER_FN is not None, "a seed runs only in a worker started by _start_seed_worker"
    return _WORKER_FN(hands, seed, keep)


class _ForkedSession:
    def __init__(self, fn: SeedFn, workers: int) -> None:
        self._pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork"),
                                         initializer=_start_seed_worker, initargs=(fn,))

    def submit(self, hands: str, seed: int, keep_states: bool) -> Future:
        return self._pool.submit(_forked_seed, (hands, seed, keep_states))

    def cancel(self, future: Future) -> None:
        future.cancel()

    def close(self, cancel: bool) -> None:
        if cancel:
            procs = list((getattr(self._pool, "_processes", None) or {}).values())
            self._pool.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                proc.kill()
            for proc in procs:
                proc.join(timeout=1.0)
        else:
            self._pool.shutdown(wait=True, cancel_futures=True)


class ForkedSeeds:
    """``workers`` forked processes on this machine (only from a process where forking is safe:
    :func:`planner.forking.pool_may_fork`); they inherit the built task instead of rebuilding it."""

    def __init__(self, workers: int) -> None:
        self.slots = max(1, int(workers))

    def open(self, fn: SeedFn) -> SeedSession:
        return _ForkedSession(fn, self.slots)
