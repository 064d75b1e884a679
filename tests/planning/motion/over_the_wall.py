"""A wall in joint space for the path-shortening tests: |q0 - 2| < 0.5 and q1 < 1 is invalid, so a path from q0 = 0
to q0 = 4 must climb over it in joint 1; the other joints are free."""

from __future__ import annotations

import numpy as np


def wall(Q: np.ndarray, shrink: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Validity of states Q (N, n) against the wall shrunk by ``shrink`` on each side (margins all 1)."""
    Q = np.atleast_2d(Q)
    return ~((np.abs(Q[:, 0] - 2.0) < 0.5 - shrink) & (Q[:, 1] < 1.0 - shrink)), np.ones(len(Q))


def over_the_wall(rng: np.random.Generator, x: np.ndarray, y: np.ndarray, others: int, spread: float) -> np.ndarray:
    """The path through (x, y) in joints 0-1 with ``others`` more joints at random in +-``spread`` at its interior
    waypoints (0 at its ends)."""
    other = rng.uniform(-spread, spread, (len(x), others))
    other[0] = other[-1] = 0.0
    return np.column_stack([x, y, other])
