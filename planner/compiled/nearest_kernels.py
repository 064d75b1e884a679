"""Compiled nearest-node search of a T-RRT tree: the index of the node closest to a point.

Why compiled: the survey's exploration asks for a tree's nearest node once per sample (tens of
thousands of times per seed), on trees of tens to a few thousand nodes of the waist and one arm
(10-12 joints). In numpy each query costs five array operations and their temporaries; the loop
below does the same work without them. It sums
each squared distance in numpy's own order, so it picks the node numpy's argmin would, ties included,
and a seed explores to the bit as it would in numpy.
"""

from __future__ import annotations

import numpy as np

from planner.compiled.jit import njit


def nearest_node(nodes: np.ndarray, size: int, q: np.ndarray) -> tuple[int, float]:
    """The index of the first of ``nodes[:size]`` (size, d) float64 at the least Euclidean distance from
    ``q`` (d,) float64, and that squared distance: the same index as
    ``argmin(((nodes[:size] - q) ** 2).sum(axis=1))``, and the same sum, to the bit."""
    i, d2 = _nearest(nodes, size, q)
    return int(i), float(d2)


@njit(cache=True, nogil=True)
def _nearest(nodes, size, q):  # pragma: no cover - compiled
    best = 0
    best_d = np.inf
    t = np.empty(q.shape[0])
    for i in range(size):
        for k in range(q.shape[0]):
            t[k] = (nodes[i, k] - q[k]) * (nodes[i, k] - q[k])
        d = _numpy_sum(t)
        if d < best_d:
            best_d = d
            best = i
    return best, best_d


@njit(cache=True, nogil=True)
def _numpy_sum(t):  # pragma: no cover - compiled
    """numpy's own order of summing a short row (its pairwise sum: below 8 terms in turn, else eight
    running sums combined in pairs, then the rest), so that distances, and ties, come out as numpy's."""
    n = t.shape[0]
    if n < 8:
        res = 0.0
        for i in range(n):
            res += t[i]
        return res
    r0, r1, r2, r3, r4, r5, r6, r7 = t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7]
    i = 8
    while i < n - (n % 8):
        r0 += t[i]
        r1 += t[i + 1]
        r2 += t[i + 2]
        r3 += t[i + 3]
        r4 += t[i + 4]
        r5 += t[i + 5]
        r6 += t[i + 6]
        r7 += t[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += t[i]
        i += 1
    return res
