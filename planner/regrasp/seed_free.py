"""The results of a search's seed-free steps, shared by searches of one problem under different seeds.

A survey row explores the planner's key paths for several key-path seeds (:mod:`planner.survey.key_paths`):
the same task searched once per seed. Most of each search does not depend on the seed at all: the
batched IK from the home posture, every IK whose first attempt (from its given start, which draws
nothing from the generator) converges, the nearest stable posture of a given state (a deterministic
optimisation), the validity checks of given states, the handover poses. Only restarts draw from a node's generator. A
:class:`SeedFreeResults` keeps those results, keyed by their exact inputs, so that the pool's searches
compute each once; a search given one returns exactly what it would have computed (a hit skips only
work whose outcome the key fixes, and never a draw from a generator).

Owned by whoever runs the searches (a survey's key-path pool); a plan's own search has none.
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np

from planner.array_keys import exact_bytes
from planner.motion.ik_batch import BatchIkResult


class SeedFreeResults:
    """Seed-free results of one problem's searches (see the module's docstring), keyed by their inputs."""

    def __init__(self) -> None:
        self._ik: dict[tuple, np.ndarray] = {}
        self._batches: dict[tuple, BatchIkResult] = {}
        self._postures: dict[tuple, np.ndarray | None] = {}
        self._checks: dict[tuple, tuple[list, np.ndarray]] = {}
        #: the task's handover poses (deterministic), once one search has computed them
        self.handover_poses: list | None = None
        #: lookups answered without computing, by kind
        self.hits: dict[str, int] = {"ik": 0, "batch_ik": 0, "posture": 0, "checks": 0}

    def ik(self, solver_name: str, solver, targets: Mapping[str, np.ndarray], seed_q: np.ndarray,
           rng: np.random.Generator, rest_q: np.ndarray) -> np.ndarray | None:
        """``solver.solve(targets, seed_q, rng, rest_q).q``; a solution found by the first attempt (which
        starts at ``seed_q`` and draws nothing from ``rng``) is kept and handed out again for the same inputs."""
        key = (solver_name, tuple((s, exact_bytes(targets[s])) for s in sorted(targets)), exact_bytes(seed_q),
               exact_bytes(rest_q))
        q = self._ik.get(key)
        if q is not None:
            self.hits["ik"] += 1
            return q.copy()
        res = solver.solve(targets, seed_q, rng, rest_q)
        if res.q is not None and res.attempts == 1:
            self._ik[key] = res.q.copy()
        return res.q

    def batch_ik(self, key: tuple, solve: Callable[[], BatchIkResult]) -> BatchIkResult:
        """``solve()`` (a batched IK without any draw), computed once per ``key``; a fresh copy each time."""
        res = self._batches.get(key)
        if res is None:
            res = self._batches[key] = solve()
        else:
            self.hits["batch_ik"] += 1
        return res.take(np.arange(len(res.ok)))

    def posture(self, key: tuple, solve: Callable[[], np.ndarray | None]) -> np.ndarray | None:
        """``solve()`` (the nearest stable posture, deterministic), computed once per ``key``; a fresh copy."""
        if key in self._postures:
            self.hits["posture"] += 1
            q = self._postures[key]
        else:
            q = self._postures[key] = solve()
        return None if q is None else q.copy()


    def checks(self, key: tuple, solve: Callable[[], tuple[list, np.ndarray]]) -> tuple[list, np.ndarray]:
        """``solve()`` (the first failing cause and min margin of runs of states: deterministic), computed once
        per ``key``; fresh copies."""
        if key in self._checks:
            self.hits["checks"] += 1
            causes, margins = self._checks[key]
        else:
            causes, margins = self._checks[key] = solve()
        return list(causes), margins.copy()

