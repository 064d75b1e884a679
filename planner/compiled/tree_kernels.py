"""Compiled inner loops of the batched kinematics: the joint-tree walk and the weighted CoM sum.

Why compiled: a batch of a T-RRT extension is ~40 configurations, and a numpy walk of the joint
tree spends its time in call overhead, not arithmetic (hundreds of array operations per batch
whatever its size). numba compiles these two loops once per machine (``cache=True``: the machine
code is kept next to this file, or in numba's user cache when that is read-only), after which a
batch costs what its arithmetic costs (``benchmarks/bench_stability.py`` prints the rate).

A tree is a :class:`TreeSpec`: slots in parent-before-child order, each a fixed placement in its
parent slot's frame followed by a one-degree-of-freedom joint driven by one column of the
configuration. Outputs use the layout of :mod:`planner.kinematics.batch`: rotations
``(slots, 3, 3, N)`` and positions ``(slots, 3, N)``, so ``R[k]`` is the ``(3, 3, N)`` block of slot k.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planner.compiled.jit import njit

#: Joint kinds: revolute about a principal axis, prismatic along one, their unaligned variants, and
#: fixed (the placement alone: a root whose frame the caller fills in, or a rigid attachment).
KIND_CODE = {"R": 0, "P": 1, "RU": 2, "PU": 3, "F": 4}


@dataclass(frozen=True)
class TreeSpec:
    """Slots of a joint tree. ``parent[k] < 0``: the placement is in the world frame."""

    parent: np.ndarray  # (S,) int64
    R0: np.ndarray  # (S, 3, 3) fixed rotation of the placement
    p0: np.ndarray  # (S, 3) fixed translation of the placement
    kind: np.ndarray  # (S,) int64, KIND_CODE
    axis_index: np.ndarray  # (S,) int64, principal axis (kinds R and P)
    axis: np.ndarray  # (S, 3) unit axis
    col: np.ndarray  # (S,) int64, configuration column driving the joint
    mult: np.ndarray  # (S,) joint value = q[col] * mult + offset
    offset: np.ndarray  # (S,)

    @property
    def size(self) -> int:
        return int(self.parent.size)


def tree_spec(parent: Sequence[int], R0: Sequence[np.ndarray | None], p0: Sequence[np.ndarray], kind: Sequence[str],
              axis_index: Sequence[int], axis: Sequence[np.ndarray], col: Sequence[int], mult: Sequence[float],
              offset: Sequence[float]) -> TreeSpec:
    """A :class:`TreeSpec` from per-slot values (``R0`` None: identity)."""
    n = len(parent)
    if any(int(a) >= k for k, a in enumerate(parent)):
        raise ValueError("every slot's parent must come before it")
    return TreeSpec(
        parent=np.asarray(parent, dtype=np.int64).reshape(n),
        R0=np.array([np.eye(3) if r is None else np.asarray(r, float) for r in R0]).reshape(n, 3, 3),
        p0=np.asarray(p0, dtype=float).reshape(n, 3),
        kind=np.array([KIND_CODE[k] for k in kind], dtype=np.int64).reshape(n),
        axis_index=np.asarray(axis_index, dtype=np.int64).reshape(n),
        axis=np.array([np.asarray(v, float) / (np.linalg.norm(v) or 1.0) for v in axis]).reshape(n, 3),
        col=np.asarray(col, dtype=np.int64).reshape(n),
        mult=np.asarray(mult, dtype=float).reshape(n),
        offset=np.asarray(offset, dtype=float).reshape(n),
    )


#: A slot whose frame the caller fills in before the walk (a root: the floating base, or the frame
#: an arm chain hangs from).
ROOT_SLOT = {"parent": -1, "R0": None, "p0": np.zeros(3), "kind": "F", "axis_index": 0, "axis": np.zeros(3), "col": 0,
             "mult": 1.0, "offset": 0.0}


def tree_from_rows(rows: Sequence[dict]) -> TreeSpec:
    """A :class:`TreeSpec` from one dict of :func:`tree_spec`'s arguments per slot."""
    return tree_spec(**{k: [r[k] for r in rows] for k in ROOT_SLOT})


def walk(spec: TreeSpec, Q: np.ndarray, R: np.ndarray, p: np.ndarray, first: int = 0, root_varies: bool = False) -> None:
    """Fill slots ``first..`` of ``R`` (S, 3, 3, N) and ``p`` (S, 3, N) for the configurations ``Q``
    (N, nq); slots before ``first`` must already hold their frames (a given root; ``root_varies`` when it
    differs between configurations).

    A slot whose joint value and whose ancestors are the same in every configuration (a batch moves a
    few joints) is computed once and copied: the same numbers, without the arithmetic."""
    _walk(np.ascontiguousarray(Q, dtype=float), spec.parent, spec.R0, spec.p0, spec.kind, spec.axis_index, spec.axis,
          spec.col, spec.mult, spec.offset, first, R, p, root_varies)


def weighted_sum(R: np.ndarray, p: np.ndarray, slots: np.ndarray, mass: np.ndarray, lever: np.ndarray,
                 base_moment: np.ndarray, total_mass: float) -> np.ndarray:
    """(base_moment + sum over ``slots`` of mass * (p + R lever)) / total_mass per configuration: (N, 3).
    The CoM of bodies fixed to the slots' frames, plus a constant moment."""
    out = np.empty((R.shape[3], 3))
    _weighted_sum(R, p, slots, mass, lever, base_moment, float(total_mass), out)
    return out


@njit(cache=True, nogil=True)
def _walk(Q, parent, R0, p0, kind, axis_index, axis, col, mult, offset, first, R, p, root_varies):  # pragma: no cover - compiled
    rot = np.empty((3, 3))
    N = Q.shape[0]
    column_varies = np.zeros(Q.shape[1], dtype=np.bool_)
    for c in range(Q.shape[1]):
        for n in range(1, N):
            if Q[n, c] != Q[0, c]:
                column_varies[c] = True
                break
    varies = np.zeros(parent.shape[0], dtype=np.bool_)
    for k in range(first):
        varies[k] = root_varies
    for k in range(first, parent.shape[0]):
        a = parent[k]
        c = col[k]
        kd = kind[k]
        ii = (axis_index[k] + 1) % 3
        jj = (axis_index[k] + 2) % 3
        varies[k] = (a >= 0 and varies[a]) or (kd <= 3 and c >= 0 and column_varies[c])
        for n in range(N if varies[k] else min(N, 1)):  # states innermost: the arrays' last axis
            th = Q[n, c] * mult[k] + offset[k]
            if a >= 0:
                for i in range(3):
                    v = p[a, i, n]
                    for m in range(3):
                        v += R[a, i, m, n] * p0[k, m]
                    p[k, i, n] = v
                    for j in range(3):
                        v = 0.0
                        for m in range(3):
                            v += R[a, i, m, n] * R0[k, m, j]
                        R[k, i, j, n] = v
            else:
                for i in range(3):
                    p[k, i, n] = p0[k, i]
                    for j in range(3):
                        R[k, i, j, n] = R0[k, i, j]
            if kd == 0:
                cs = np.cos(th)
                sn = np.sin(th)
                for i in range(3):
                    ci = R[k, i, ii, n]
                    cj = R[k, i, jj, n]
                    R[k, i, ii, n] = cs * ci + sn * cj
                    R[k, i, jj, n] = cs * cj - sn * ci
            elif kd == 1 or kd == 3:
                for i in range(3):
                    p[k, i, n] += th * (R[k, i, 0, n] * axis[k, 0] + R[k, i, 1, n] * axis[k, 1] + R[k, i, 2, n] * axis[k, 2])
            elif kd == 2:  # unaligned revolute: R @ (I + sin K + (1 - cos) K^2), K the axis' cross-product matrix
                x, y, z = axis[k, 0], axis[k, 1], axis[k, 2]
                cs = np.cos(th)
                sn = np.sin(th)
                t = 1.0 - cs
                rot[0, 0] = 1.0 - t * (y * y + z * z)
                rot[0, 1] = -sn * z + t * x * y
                rot[0, 2] = sn * y + t * x * z
                rot[1, 0] = sn * z + t * x * y
                rot[1, 1] = 1.0 - t * (x * x + z * z)
                rot[1, 2] = -sn * x + t * y * z
                rot[2, 0] = -sn * y + t * x * z
                rot[2, 1] = sn * x + t * y * z
                rot[2, 2] = 1.0 - t * (x * x + y * y)
                for i in range(3):
                    r0 = R[k, i, 0, n] * rot[0, 0] + R[k, i, 1, n] * rot[1, 0] + R[k, i, 2, n] * rot[2, 0]
                    r1 = R[k, i, 0, n] * rot[0, 1] + R[k, i, 1, n] * rot[1, 1] + R[k, i, 2, n] * rot[2, 1]
                    r2 = R[k, i, 0, n] * rot[0, 2] + R[k, i, 1, n] * rot[1, 2] + R[k, i, 2, n] * rot[2, 2]
                    R[k, i, 0, n], R[k, i, 1, n], R[k, i, 2, n] = r0, r1, r2
        if not varies[k]:
            for n in range(1, N):
                for i in range(3):
                    p[k, i, n] = p[k, i, 0]
                    for j in range(3):
                        R[k, i, j, n] = R[k, i, j, 0]


@njit(cache=True, nogil=True)
def _weighted_sum(R, p, slots, mass, lever, base_moment, total_mass, out):  # pragma: no cover - compiled
    N = R.shape[3]
    for n in range(N):
        out[n, 0] = base_moment[0]
        out[n, 1] = base_moment[1]
        out[n, 2] = base_moment[2]
    for t in range(slots.shape[0]):  # slots outermost, states innermost: the arrays' last axis
        k = slots[t]
        m = mass[t]
        lx, ly, lz = lever[t, 0], lever[t, 1], lever[t, 2]
        for i in range(3):
            for n in range(N):
                out[n, i] += m * (p[k, i, n] + R[k, i, 0, n] * lx + R[k, i, 1, n] * ly + R[k, i, 2, n] * lz)
    for n in range(N):
        out[n, 0] /= total_mass
        out[n, 1] /= total_mass
        out[n, 2] /= total_mass
