"""Why the planner refused a state, a node or a motion: one enum, carried from the check that failed to
the plan document's failures and its failure code.

A :class:`FailureCause` is a ``str`` (its value is what the plan document shows, ``"com_margin"``), so
counters keyed by it serialise as before; its ``repr`` is its value's, so a message listing failures
by cause reads ``{'com_margin': 3}``.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from types import MappingProxyType


class FailureCause(StrEnum):
    """Why a check refused what it checked."""

    IK = "ik"  #: no joint configuration reaches the pose
    COLLISION = "collision"  #: the robot, the object or the environment touch where they must not
    COM_MARGIN = "com_margin"  #: the CoM margin (with the held object) is below the threshold
    MOTION = "motion"  #: no valid motion between two key poses
    EFFORT = "effort"  #: a joint's static torque is over its effort limit
    GRIP = "grip"  #: the grip slips (the object's weight or moment about the jaw's closing axis)

    def __repr__(self) -> str:
        return repr(self.value)

    @property
    def code(self) -> str:
        """The plan's failure code when this cause dominates (docs/contract.md section 3)."""
        return _CODES[self]


_CODES = MappingProxyType({
    FailureCause.IK: "IK_FAIL", FailureCause.COLLISION: "COLLISION", FailureCause.COM_MARGIN: "COM_MARGIN",
    FailureCause.MOTION: "MOTION", FailureCause.EFFORT: "EFFORT", FailureCause.GRIP: "GRIP",
})

#: How a person reads each cause in a message.
_WORDS = MappingProxyType({
    FailureCause.IK: "IK", FailureCause.COLLISION: "collision", FailureCause.COM_MARGIN: "CoM margin",
    FailureCause.MOTION: "motion", FailureCause.EFFORT: "effort", FailureCause.GRIP: "grip",
})


def failures_in_words(failures: Mapping[str, int], what: str = "removed") -> str:
    """Failures counted by cause as words for people: ``"12 removed (IK 5, collision 7)"``, the largest
    first, ``"0 removed"`` when there are none (never a raw dict in a message)."""
    counts = sorted(((c, n) for c, n in failures.items() if n), key=lambda cn: (-cn[1], str(cn[0])))
    if not counts:
        return f"0 {what}"
    parts = ", ".join(f"{_WORDS.get(c, str(c).replace('_', ' '))} {n}" for c, n in counts)  # type: ignore[call-overload]
    return f"{sum(n for _, n in counts)} {what} ({parts})"
