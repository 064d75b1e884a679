"""The planner's one error hierarchy.

Two kinds of failure leave the planner as exceptions; everything else is a result (a plan or
survey document with ``status: infeasible`` and its failures counted by cause):

- :class:`InputError`: the request cannot be planned as given (an unknown name, a malformed
  value, an impossible pose). Its message says what is wrong; callers show it as a usage error.
- :class:`Canceled`: the job's termination condition asked the work to stop (a cancel request,
  or a deadline passed inside a long step). One type for every layer, so nothing translates it.

Every domain-specific input error derives from :class:`InputError` (and from ``ValueError``, so
code that catches the built-in keeps working).
"""

from __future__ import annotations


class PlannerError(Exception):
    """Base of every error the planner raises on purpose."""


class Canceled(PlannerError):
    """The work was asked to stop before it finished (cancel request or deadline)."""


class InputError(PlannerError, ValueError):
    """The request cannot be planned as given; the message names the problem."""


class UnknownNameError(InputError):
    """A joint, frame or link name that the robot model does not have."""


class UnknownRobotError(InputError):
    """A robot name that no spec file provides; the message lists the valid ones."""


class ScenarioError(InputError):
    """A scenario file or name that cannot be read or does not validate."""


class StanceError(InputError):
    """A stance that cannot be built (unknown name, unreachable feet, bad definition)."""


class ObjectModelError(InputError):
    """An object description that cannot be turned into a solid with mass properties."""


class PlacementError(InputError):
    """The object's start or goal pose is not a valid resting pose (``end`` says which)."""

    def __init__(self, message: str, end: str | None = None):
        super().__init__(message)
        self.end = end


class DegeneratePolygonError(InputError):
    """Soles whose convex hull has no area (no support polygon)."""


class DerivationError(PlannerError, RuntimeError):
    """A robot model could not be derived from its upstream description package."""
