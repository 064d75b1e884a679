"""When a planner must stop: OMPL's ``PlannerTerminationCondition`` for this project.

One object carries the three reasons a long computation ends early, so that every layer takes
one argument instead of three: the iteration cap (the reproducible stop: seeded runs stop on
iterations, never on the clock), the deadline (a safety net: the run ends ``TIMEOUT``), and a
cancel request (the job's context; the run raises :class:`planner.errors.Canceled`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable


def _never() -> bool:
    return False


@dataclass(frozen=True)
class Termination:
    """An iteration cap, a deadline (``time.monotonic()`` seconds) and a cancel predicate."""

    max_iterations: int
    time_limit_s: float = math.inf
    canceled: Callable[[], bool] = _never
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

    def with_iterations(self, max_iterations: int) -> Termination:
        """The same deadline and cancel predicate with another iteration cap."""
        return replace(self, max_iterations=max_iterations)
