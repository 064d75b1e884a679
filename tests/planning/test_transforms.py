"""SE(3) helpers: round trips and conventions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.transforms import (
    axis_angle_to_matrix,
    inverse,
    matrices_to_pose7,
    matrix_to_axis_angle,
    matrix_to_pose7,
    matrix_to_rpy,
    pose7_to_matrix,
    rpy_to_matrix,
)

finite = st.floats(-1.0, 1.0, allow_nan=False)
quat = st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 0.1)


@settings(max_examples=60, deadline=None)
@given(st.tuples(finite, finite, finite), quat)
def test_pose7_round_trip(p, q):
    q = np.array(q) / np.linalg.norm(q)
    T = pose7_to_matrix([*p, *q])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    back = matrix_to_pose7(T)
    assert np.allclose(back[:3], p)
    # same rotation up to the quaternion sign
    assert np.allclose(pose7_to_matrix(back), T, atol=1e-9)
    assert back[6] >= 0


@settings(max_examples=60, deadline=None)
@given(st.tuples(finite, finite, finite), st.tuples(finite, finite, finite))
def test_inverse_and_rpy(p, rpy):
    R = rpy_to_matrix(*[3 * a for a in rpy])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    assert np.allclose(T @ inverse(T), np.eye(4), atol=1e-12)
    assert np.allclose(rpy_to_matrix(*matrix_to_rpy(R)), R, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.tuples(finite, finite, finite).filter(lambda a: np.linalg.norm(a) > 0.1), st.floats(0.0, 3.1))
def test_axis_angle_round_trip(axis, angle):
    R = axis_angle_to_matrix(np.array(axis), angle)
    k, a = matrix_to_axis_angle(R)
    assert np.allclose(axis_angle_to_matrix(k, a), R, atol=1e-7)


def test_bad_pose_is_named():
    with pytest.raises(ValueError, match="7 numbers"):
        pose7_to_matrix([0, 0, 0])
    with pytest.raises(ValueError, match="non-finite"):
        pose7_to_matrix([0, 0, float("nan"), 0, 0, 0, 1])


def test_batch_pose_conversion_covers_every_branch():
    """Shepperd's method picks one of four formulas per row (the trace or the largest diagonal
    term); a batch mixing them converts every row as if alone."""
    rng = np.random.default_rng(3)
    quats = [[0, 0, 0, 1], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0.6, 0.8, 0, 0]]
    quats += list(rng.normal(size=(20, 4)))
    T = np.stack([pose7_to_matrix([k, -k, 0.5 * k, *(np.array(q) / np.linalg.norm(q))]) for k, q in enumerate(quats)])
    out = matrices_to_pose7(T)
    assert out.shape == (len(T), 7)
    for k in range(len(T)):
        assert out[k, 6] >= 0
        assert np.allclose(pose7_to_matrix(out[k]), T[k], atol=1e-12)
        assert np.allclose(matrix_to_pose7(T[k]), out[k], atol=0)
