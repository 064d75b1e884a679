"""Lookup keys of numpy arrays by their exact values: for results computed once per exact input and asked for again
(a survey's seed-free results, a plan's path terms at its gridpoints)."""

from __future__ import annotations

import hashlib

import numpy as np


def exact_bytes(a: np.ndarray) -> bytes:
    """The array's values as float64 bytes, C order: equal exactly when the values are."""
    return np.ascontiguousarray(a, dtype=float).tobytes()


def array_key(*arrays: np.ndarray | None) -> tuple:
    """A lookup key of arrays by their exact values (None stays None)."""
    return tuple(None if a is None else exact_bytes(a) for a in arrays)


def array_digest(*arrays: np.ndarray) -> bytes:
    """A 32-byte lookup key of arrays by their exact values, for arrays too large to keep as :func:`array_key`
    keeps them: a BLAKE2b digest of their shapes and values (a collision is not to be expected)."""
    h = hashlib.blake2b(digest_size=32)
    for a in arrays:
        h.update(repr(np.shape(a)).encode())
        h.update(exact_bytes(a))
    return h.digest()
