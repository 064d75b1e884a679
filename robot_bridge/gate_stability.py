"""The gate's stability checks on its sample grid: feet, CoM margin (between points too) and ZMP.

Exact kinematics at every sample (:class:`robot_bridge.urdf_kinematics.BatchFK`), the
support polygon from the URDF's soles (:mod:`robot_bridge.support`): never the plan's numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gate_context import _Context, _first
from .gate_parse import _Parsed
from .gate_types import GateSettings, Veto
from .support import Polygon
from .urdf_kinematics import BatchFK


@dataclass(frozen=True)
class _Grid:
    """The gate's samples: ``S`` per plan interval (controller periods x oversample), then the last point."""

    n: int
    columns: list[np.ndarray]  # per joint (plan order): its n values, or its one value when it holds still
    obj_p: np.ndarray  # (n, 3) object position
    obj_q: np.ndarray  # (n, 4) object quaternion, unit
    point: np.ndarray  # (n,) the plan point whose interval a sample lies in


def _interpolate(p: _Parsed, S: int) -> _Grid:
    """Linear interpolation onto the gate's grid, as the controller plays it.

    A joint that holds one value at every point keeps it in between, so only the moving
    columns are interpolated (plans move a few joints at a time), and the kinematics
    treat the others as constants.
    """
    n, nq = p.n, p.Q.shape[1]
    quat = p.object_pose[:, 3:] / np.linalg.norm(p.object_pose[:, 3:], axis=1, keepdims=True)
    m = (n - 1) * S + 1  # one point: a grid of one sample, that point
    f = np.arange(S) / S

    def lerp(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Rows of a (n, k) and b (n - 1, k) deltas onto the grid: (m, k), written in place."""
        out = np.empty((m, a.shape[1]))
        body = out[:-1].reshape(n - 1, S, a.shape[1])
        np.multiply(f[None, :, None], b[:, None, :], out=body)
        body += a[:-1, None, :]
        out[-1] = a[-1]
        return out

    moving = p.moving
    Qm = p.Q[:, moving]
    rows = lerp(Qm, np.diff(Qm, axis=0)).T.copy()  # (moving joints, m): contiguous per joint
    columns = [p.Q[:1, k] for k in range(nq)]
    for r, k in enumerate(moving):
        columns[k] = rows[r]
    pos = p.object_pose[:, :3]
    P = lerp(pos, np.diff(pos, axis=0))
    q1 = quat[1:] * np.where(np.sum(quat[:-1] * quat[1:], axis=1, keepdims=True) < 0, -1.0, 1.0)  # shortest way
    Qt = lerp(quat, q1 - quat[:-1])
    Qt /= np.linalg.norm(Qt, axis=1, keepdims=True)
    point = np.minimum(np.arange(m) // S, n - 1)
    return _Grid(m, columns, P, Qt, point)


def _rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) ``[x, y, z, w]`` applied to one vector v (3,): (n, 3), without matrices."""
    u, w = quat[:, :3], quat[:, 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _check_stability(ctx: _Context, p: _Parsed, fk: BatchFK, polygon: Polygon, s: GateSettings) -> None:
    S = ctx.S
    grid = _interpolate(p, S)
    frames = [f["frame"] for f in p.feet]
    # Exact kinematics at every sample of the grid (controller samples and midpoints).
    robot_com, feet = fk.com_and_points(p.base_pose, grid.columns, grid.n, frames)
    obj_com = grid.obj_p + _rotate(grid.obj_q, p.com_local)
    held = p.holding[grid.point] != 0
    need = ctx.threshold - s.margin_tolerance_m

    # Feet stay where the stance puts them (the polygon below assumes it).
    worst = 0.0
    for foot in p.feet:
        dev = np.linalg.norm(feet[foot["frame"]] - foot["pose"][:3], axis=1)
        k = int(np.argmax(dev))
        worst = max(worst, float(dev[k]))
        if dev[k] > s.feet_tolerance_m:
            first = _first(dev > s.feet_tolerance_m)
            raise Veto("feet", f"sole {foot['frame']} is {dev[first] * 1000:.2f} mm from its stance placement "
                       f"(tolerance {s.feet_tolerance_m * 1000:.1f} mm)", first)
    ctx.passed("feet", max_deviation_m=worst)

    # System CoM (paper eq. 1): robot plus the object while it is held.
    M, m = fk.total_mass, p.mass

    def system(mask: np.ndarray, r: np.ndarray, o: np.ndarray) -> np.ndarray:
        w = m * mask[:, None]
        return (M * r + w * o) / (M + w)

    com = system(held, robot_com, obj_com)
    margin = polygon.margin(com[:, :2])
    below = f"the threshold {ctx.threshold * 1000:.2f} mm"
    if ctx.recovery and margin[0] < ctx.threshold:
        need = float(margin[0]) - s.margin_tolerance_m
        below = f"the recovery's floor {margin[0] * 1000:.2f} mm (where it starts, under the threshold)"
        ctx.note("com_margin", recovery_floor_m=float(margin[0]))
    k = int(np.argmin(margin))
    ctx.note("com_margin", min_margin_m=float(margin[k]), at_sample=k, threshold_m=ctx.threshold,
             polygon=polygon.vertices.tolist())
    first = _first(margin < need)
    value = float(margin[first]) if first is not None else None
    # Where holding changes at a point, the state there is checked with both values.
    change = np.flatnonzero(p.holding[1:] != p.holding[:-1]) + 1
    if change.size:
        ks = change * S
        before = p.holding[change - 1] != 0
        m2 = polygon.margin(system(before, robot_com[ks], obj_com[ks])[:, :2])
        ctx.note("com_margin", min_margin_at_holding_changes_m=float(m2.min()))
        bad2 = np.flatnonzero(m2 < need)
        if bad2.size and (first is None or ks[bad2[0]] < first):
            first, value = int(ks[bad2[0]]), float(m2[bad2[0]])  # the mass set before the change fails first
    if first is not None:
        raise Veto("com_margin", f"the CoM margin falls to {value * 1000:.2f} mm, below {below} "
                   f"(tolerance {s.margin_tolerance_m * 1000:.2f} mm)", first)
    ctx.passed("com_margin")

    # ZMP (cart-table) at every controller sample (5 ms; the plan's points among them),
    # c'' by central differences at dt_s (the contract's step, S gate samples) along the
    # interpolated path. The three states of a stencil use the sample's mass set, so
    # grasping an object is not mistaken for an acceleration; the plan is at rest before
    # and after. With dt_s = 5 ms the controller samples are the plan's points.
    ctrl = np.arange(0, grid.n, s.oversample)
    hk = held[ctrl]
    prev, nxt = np.maximum(ctrl - S, 0), np.minimum(ctrl + S, grid.n - 1)
    c = com[ctrl]
    c_prev = system(hk, robot_com[prev], obj_com[prev])
    c_next = system(hk, robot_com[nxt], obj_com[nxt])
    acc = (c_next[:, :2] - 2.0 * c[:, :2] + c_prev[:, :2]) / (p.dt * p.dt)
    zmp = c[:, :2] - (c[:, 2:3] / s.gravity) * acc
    zm = polygon.margin(zmp)
    k = int(np.argmin(zm))
    ctx.note("zmp", min_margin_m=float(zm[k]), at_sample=int(ctrl[k]), controller_samples=int(ctrl.size))
    row = _first(zm < -s.zmp_tolerance_m)
    if row is not None:
        g = int(ctrl[row])
        where = f"point {g // S}" if g % S == 0 else f"t = {g * p.dt / S:.4f} s, between points {g // S} and {g // S + 1}"
        raise Veto("zmp", f"the ZMP leaves the support polygon by {-zm[row] * 1000:.2f} mm at {where}", g)
    ctx.passed("zmp")
