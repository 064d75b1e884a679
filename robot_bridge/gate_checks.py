"""The gate's per-point checks: finite values, time, start state, joint positions, velocities, accelerations."""

from __future__ import annotations

import numpy as np

from .gate_context import _Context, _first
from .gate_parse import _Parsed
from .gate_types import GateSettings, MeasuredState, Veto, _Robot


def _check_finite(ctx: _Context, p: _Parsed) -> None:
    for what, arr in (("q", p.Q), ("object_pose", p.object_pose), ("t", p.t[:, None])):
        if np.isfinite(arr).all():
            continue
        bad = ~np.isfinite(arr)
        row = _first(bad.any(axis=1))
        if row is not None:
            col = int(np.flatnonzero(bad[row])[0])
            label = f"{what}[{col}] ({p.joint_names[col]})" if what == "q" else f"{what}[{col}]" if what != "t" else "t"
            raise Veto("finite", f"trajectory[{row}].{label} is {arr[row, col]}; every value must be finite", row * ctx.S)
    for k, foot in enumerate(p.feet):
        if not np.all(np.isfinite(foot["pose"])):
            raise Veto("finite", f"stance.feet[{k}].pose is not finite")
    if not (np.all(np.isfinite(p.base_pose)) and np.all(np.isfinite(p.com_local))):
        raise Veto("finite", "stance.base_pose or object.com_local is not finite")
    norms = np.linalg.norm(p.object_pose[:, 3:], axis=1)
    row = _first(np.abs(norms - 1.0) > 1e-3)
    if row is not None:
        raise Veto("finite", f"trajectory[{row}].object_pose has a quaternion of norm {norms[row]:.6f}", row * ctx.S)


def _check_time(ctx: _Context, p: _Parsed, s: GateSettings) -> None:
    if p.n >= 2:
        steps = np.diff(p.t)
        row = _first(steps <= 0.0)
        if row is not None:
            raise Veto("time", f"time does not increase strictly: t[{row + 1}] = {p.t[row + 1]!r} after t[{row}] = {p.t[row]!r}",
                       (row + 1) * ctx.S)
    expected = np.arange(p.n) * p.dt
    off = np.abs(p.t - expected)
    row = _first(off > s.time_tolerance_s + 1e-12 * np.abs(expected))
    if row is not None:
        raise Veto("time", f"t[{row}] = {p.t[row]!r} s, expected {expected[row]!r} s (uniform dt_s = {p.dt})", row * ctx.S)
    ctx.passed("time", duration_s=float(p.t[-1]), dt_s=p.dt, samples_per_point=ctx.S)


def _check_start(ctx: _Context, p: _Parsed, measured: MeasuredState, s: GateSettings) -> None:
    tol = measured.tolerance_rad if measured.tolerance_rad is not None else s.start_tolerance_rad
    index = {n: i for i, n in enumerate(measured.joint_names)}
    missing = [n for n in p.joint_names if n not in index]
    if missing:
        raise Veto("start_state", f"the measured state lacks joints {missing}", 0)
    qm = np.array([measured.q[index[n]] for n in p.joint_names], dtype=float)
    if not np.all(np.isfinite(qm)):
        raise Veto("start_state", "the measured state is not finite", 0)
    dev = np.abs(p.Q[0] - qm)
    worst = int(np.argmax(dev))
    ctx.note("start_state", max_deviation=float(dev[worst]), joint=p.joint_names[worst], tolerance=tol)
    if dev[worst] > tol:
        raise Veto("start_state", f"the first point is {dev[worst]:.4f} from the measured state at joint {p.joint_names[worst]} "
                   f"(plan {p.Q[0, worst]:.4f}, robot {qm[worst]:.4f}; tolerance {tol})", 0)
    ctx.passed("start_state")


def _limits(robot: _Robot, p: _Parsed) -> tuple[np.ndarray, np.ndarray]:
    order = {n: i for i, n in enumerate(robot.model.joint_names)}
    idx = np.array([order[n] for n in p.joint_names])
    return robot.model.lower[idx], robot.model.upper[idx]


def _check_position(ctx: _Context, p: _Parsed, lower: np.ndarray, upper: np.ndarray, s: GateSettings) -> None:
    tol = s.position_tolerance
    qmin, qmax = p.Q.min(axis=0), p.Q.max(axis=0)  # column extremes first: the full mask only on a violation
    ctx.note("joint_position", min_clearance=float(np.min(np.minimum(qmin - lower, upper - qmax))))
    if np.any(qmin < lower - tol) or np.any(qmax > upper + tol):
        bad = (p.Q < lower - tol) | (p.Q > upper + tol)
        row = _first(bad.any(axis=1))
        col = int(np.flatnonzero(bad[row])[0])
        raise Veto("joint_position", f"joint {p.joint_names[col]} at {p.Q[row, col]:.6f} is outside its limits "
                   f"[{lower[col]:.6f}, {upper[col]:.6f}] at point {row}", row * ctx.S)
    ctx.passed("joint_position")


def _check_rates(ctx: _Context, p: _Parsed, robot: _Robot, s: GateSettings) -> None:
    """Velocities and accelerations by finite differences at dt_s; the plan is at rest before and after.

    Only the moving columns are differenced: a joint that holds one value has none.
    """
    cols = p.moving
    if cols.size == 0:  # nothing moves: at rest throughout
        ctx.passed("joint_velocity", max_ratio=0.0)
        ctx.passed("joint_acceleration", max_ratio=0.0)
        return
    order = {n: i for i, n in enumerate(robot.model.joint_names)}
    names = [p.joint_names[c] for c in cols]
    vmax = robot.model.velocity_limit[[order[n] for n in names]]
    amax = np.array([robot.files.acceleration_limit(n) for n in names])
    rel = 1.0 + s.limit_tolerance_rel
    Q, dt = p.Q[:, cols], p.dt
    v = np.diff(Q, axis=0) / dt  # row i: from point i to i + 1
    a = np.empty_like(Q)  # at each point, with the rest state repeated before and after (a moving column: n >= 2)
    a[1:-1] = np.diff(v, axis=0) / dt
    a[0] = v[0] / dt
    a[-1] = -v[-1] / dt
    vr, ar = np.abs(v).max(axis=0) / vmax, np.abs(a).max(axis=0) / amax
    ctx.note("joint_velocity", max_ratio=float(vr.max()), joint=names[int(np.argmax(vr))])
    ctx.note("joint_acceleration", max_ratio=float(ar.max()), joint=names[int(np.argmax(ar))])
    if np.any(vr > rel):  # column peaks first: the row search only on a violation
        over = np.abs(v) > vmax * rel
        row = _first(over.any(axis=1))
        col = int(np.flatnonzero(over[row])[0])
        raise Veto("joint_velocity", f"joint {names[col]} moves at {abs(v[row, col]):.4f}, limit {vmax[col]:.4f} "
                   f"between points {row} and {row + 1}", row * ctx.S)
    ctx.passed("joint_velocity")
    if np.any(ar > rel):
        over = np.abs(a) > amax * rel
        row = _first(over.any(axis=1))
        col = int(np.flatnonzero(over[row])[0])
        raise Veto("joint_acceleration", f"joint {names[col]} accelerates at {abs(a[row, col]):.4f}, limit "
                   f"{amax[col]:.4f} at point {row}" + (" (the plan does not start/end at rest)" if row in (0, p.n - 1) else ""),
                   row * ctx.S)
    ctx.passed("joint_acceleration")
