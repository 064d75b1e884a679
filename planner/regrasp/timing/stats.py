"""The timing's stats as deltas: what a piece of work added to them, to be added again where the work is not redone
(a result kept for a second asking, a helper process's share) in a fixed order."""

from __future__ import annotations


def stats_copy(stats: dict) -> dict:
    """A copy of the timing's stats whose lists are copies too (the numbers are immutable)."""
    return {key: (list(v) if isinstance(v, list) else v) for key, v in stats.items()}


def stats_added(after: dict, before: dict) -> dict:
    """What the timing's stats ``after`` added to ``before``: the numbers' differences, the lists' new entries."""
    return {key: (v[len(before.get(key, [])):] if isinstance(v, list) else v - before.get(key, 0))
            for key, v in after.items()}


def add_stats(stats: dict, added: dict) -> None:
    """Add what :func:`stats_added` found to ``stats`` in place."""
    for key, v in added.items():
        stats[key] = stats[key] + v if key in stats else v
