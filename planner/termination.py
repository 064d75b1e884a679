"""When a planner must stop: OMPL's ``PlannerTerminationCondition`` for this project.

One object carries the three reasons a long computation ends early, so that every layer takes
one argument instead of three: the iteration cap (the reproducible stop: seeded runs stop on
iterations, never on the clock), the deadline (only the user's own budget, a scenario's
``limits.time_s``: the run then ends ``TIMEOUT`` and says how far it got; none by default), and a
cancel request (the job's context; the run raises :class:`planner.errors.Canceled`). The plan's
graph search, each T-RRT motion and each smoothing take the same object (a motion with its own
iteration cap: :meth:`Termination.with_iterations`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable


def never() -> bool:
    """The cancel predicate of work nobody cancels."""
    return False


@dataclass(frozen=True)
class Termination:
    """An iteration cap, a deadline (``time.monotonic()`` seconds) and a cancel predicate."""

    max_iterations: int
    time_limit_s: float = math.inf
    canceled: Callable[[], bool] = never
    started: float = field(default_factory=time.monotonic)

    @property
    def deadline(self) -> float:
        return self.started + self.time_limit_s

    def remaining_s(self) -> float:
        return self.deadline - time.monotonic()

    def past_deadline(self) -> bool:
        return time.monotonic() > self.deadline

    def should_stop(self) -> bool:
        """True once the work must end: cancelled, or past the deadline."""
        return self.canceled() or self.past_deadline()

    @classmethod
    def of_limits(cls, limits: Any, canceled: Callable[[], bool] = never, started: float | None = None) -> Termination:
        """A scenario's ``limits`` (:class:`schemas.scenario.Limits`): its iteration cap, and its time budget
        when the user gave one (none: no deadline)."""
        time_s = math.inf if limits.time_s is None else float(limits.time_s)
        return cls(int(limits.max_iterations), time_s, canceled, time.monotonic() if started is None else started)

    @property
    def has_deadline(self) -> bool:
        return math.isfinite(self.time_limit_s)

    def budget_text(self) -> str:
        """The user's time budget in words, for a ``TIMEOUT`` message."""
        return f"the time limit of {self.time_limit_s:g} s" if self.has_deadline else "no time limit"

    def with_iterations(self, max_iterations: int) -> Termination:
        """The same deadline and cancel predicate with another iteration cap."""
        return replace(self, max_iterations=max_iterations)
