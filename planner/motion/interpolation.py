"""Joint-space interpolation: straight lines between configurations, sampled two ways.

- :func:`interpolate`: ``n`` states from a to b, both ends included (the states a plan stores
  for a short straight move).
- :func:`edge_states` and :func:`densify`: the states that check a straight edge or a path of
  them, at most ``resolution`` rad apart per joint (the states a validity check visits).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np


def interpolate(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """(n, nq) states evenly spaced from ``a`` to ``b``, both included."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    return a[None] * (1 - s) + b[None] * s


def edge_states(a: np.ndarray, b: np.ndarray, resolution: float) -> np.ndarray:
    """States strictly after ``a`` up to ``b`` inclusive, at most ``resolution`` apart per joint."""
    n = max(1, int(math.ceil(float(np.abs(b - a).max()) / resolution - 1e-9)))
    f = np.arange(1, n + 1)[:, None] / n
    return a + f * (b - a)


def densify(waypoints: Sequence[np.ndarray], resolution: float) -> np.ndarray:
    """Every state that checks the path through ``waypoints``: the first one, then each edge's states."""
    parts = [np.asarray(waypoints[0], dtype=float)[None]]
    parts += [edge_states(a, b, resolution) for a, b in zip(waypoints[:-1], waypoints[1:])]
    return np.vstack(parts)
