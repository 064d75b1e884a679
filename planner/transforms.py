"""Small SE(3) helpers shared by the planner: poses as 7-vectors and as 4x4 matrices.

The wire format is ``[x, y, z, qx, qy, qz, qw]`` (docs/contract.md); geometry code works
with homogeneous 4x4 matrices because products and inverses are then one line.
Everything here is plain numpy so that objects, grasps, placements and collision
share one convention and one implementation.
"""

from __future__ import annotations

import numpy as np

#: Below this norm a rotation axis or quaternion is treated as degenerate.
_EPS = 1e-12


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices from quaternions ``[qx, qy, qz, qw]`` (normalised first); shape (..., 4) -> (..., 3, 3)."""
    q = np.asarray(quat, dtype=float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n < _EPS):
        raise ValueError(f"quaternion {q.tolist()} is not a rotation (norm {np.squeeze(n).tolist()})")
    x, y, z, w = np.moveaxis(q / n, -1, 0)
    out = np.empty(x.shape + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def pose7_to_matrix(pose: np.ndarray | list[float]) -> np.ndarray:
    """4x4 homogeneous matrix from ``[x, y, z, qx, qy, qz, qw]``."""
    p = np.asarray(pose, dtype=float)
    if p.shape != (7,):
        raise ValueError(f"a pose has 7 numbers [x, y, z, qx, qy, qz, qw], got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"pose {p.tolist()} has a non-finite value")
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(p[3:])
    T[:3, 3] = p[:3]
    return T


def matrix_to_pose7(T: np.ndarray) -> np.ndarray:
    """``[x, y, z, qx, qy, qz, qw]`` (qw >= 0) from a 4x4 homogeneous matrix."""
    return matrices_to_pose7(np.asarray(T, dtype=float)[None])[0]


def matrices_to_pose7(T: np.ndarray) -> np.ndarray:
    """(N, 4, 4) rigid transforms -> (N, 7) ``[x y z qx qy qz qw]`` with qw >= 0, all at once (a plan
    has thousands of points)."""
    T = np.asarray(T, dtype=float)
    R = T[:, :3, :3]
    n = T.shape[0]
    q = np.empty((n, 4))
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    # Shepperd's method, branch per row on the largest diagonal term.
    cases = np.argmax(np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1), axis=1)
    for c in range(4):
        m = cases == c
        if not m.any():
            continue
        r = R[m]
        if c == 0:
            s = np.sqrt(1.0 + tr[m]) * 2
            q[m] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 1, 0] - r[:, 0, 1]) / s, 0.25 * s], axis=1)
        elif c == 1:
            s = np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2]) * 2
            q[m] = np.stack([0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 2, 1] - r[:, 1, 2]) / s], axis=1)
        elif c == 2:
            s = np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2]) * 2
            q[m] = np.stack([(r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s, (r[:, 1, 2] + r[:, 2, 1]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s], axis=1)
        else:
            s = np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1]) * 2
            q[m] = np.stack([(r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s, (r[:, 1, 0] - r[:, 0, 1]) / s], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    return np.hstack([T[:, :3, 3], q])


def make_transform(R: np.ndarray | None = None, p: np.ndarray | None = None) -> np.ndarray:
    """4x4 matrix from a rotation and a translation (either may be omitted)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if p is not None:
        T[:3, 3] = p
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (transpose the rotation; no general matrix inverse)."""
    T = np.asarray(T, dtype=float)
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def rpy_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (URDF convention)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_to_rpy(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    R = np.asarray(R, dtype=float)
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    if abs(np.cos(pitch)) > 1e-9:
        roll = np.arctan2(R[2, 1], R[2, 2])
        yaw = np.arctan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: put everything in yaw
        roll = 0.0
        yaw = np.arctan2(-R[0, 1], R[1, 1])
    return np.array([roll, pitch, yaw])


def axis_angle_to_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation of ``angle`` rad about ``axis`` (Rodrigues)."""
    k = np.asarray(axis, dtype=float)
    n = np.linalg.norm(k)
    if n < _EPS:
        raise ValueError(f"rotation axis {k.tolist()} has zero length")
    k = k / n
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def matrix_to_axis_angle(R: np.ndarray) -> tuple[np.ndarray, float]:
    """(unit axis, angle in [0, pi]) of a rotation; the axis is x for the identity."""
    R = np.asarray(R, dtype=float)
    angle = float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    if angle < 1e-9:
        return np.array([1.0, 0.0, 0.0]), 0.0
    if np.pi - angle < 1e-6:
        # near pi: the axis is the column of R + I with the largest norm
        M = R + np.eye(3)
        col = M[:, int(np.argmax(np.linalg.norm(M, axis=0)))]
        return col / np.linalg.norm(col), angle
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * np.sin(angle))
    return axis / np.linalg.norm(axis), angle


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle (rad) of the relative rotation between two orientations."""
    return matrix_to_axis_angle(np.asarray(R_a).T @ np.asarray(R_b))[1]


def rot_x(a: float) -> np.ndarray:
    return axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), a)


def rot_y(a: float) -> np.ndarray:
    return axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), a)


def rot_z(a: float) -> np.ndarray:
    return axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), a)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    pts = np.asarray(points, dtype=float)
    return pts @ T[:3, :3].T + T[:3, 3]


def perpendicular(v: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to ``v`` and to the world axis ``v`` is least along, chosen deterministically
    (``v`` x that axis)."""
    e = np.eye(3)[int(np.argmin(np.abs(v)))]
    u = np.cross(v, e)
    return u / np.linalg.norm(u)


def frame_from_z(z: np.ndarray) -> np.ndarray:
    """A right-handed rotation whose z column is the unit vector ``z``, its x column chosen deterministically
    (the reverse of :func:`perpendicular`, to the bit)."""
    x = -perpendicular(z)
    return np.column_stack([x, np.cross(z, x), z])


def frame_from_z_y(z_axis: np.ndarray, y_hint: np.ndarray) -> np.ndarray:
    """Right-handed rotation whose z column is ``z_axis`` and y column is ``y_hint`` made orthogonal to it."""
    z = np.asarray(z_axis, dtype=float)
    z = z / np.linalg.norm(z)
    y = np.asarray(y_hint, dtype=float) - np.dot(y_hint, z) * z
    n = np.linalg.norm(y)
    if n < 1e-9:
        raise ValueError("y_hint is parallel to z_axis")
    y /= n
    x = np.cross(y, z)
    return np.column_stack([x, y, z])
