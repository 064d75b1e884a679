"""Time parameterization of a piecewise-linear joint path, with a ZMP check at execution speed.

Each straight segment of the path is timed rest to rest with one trapezoidal
velocity profile shared by every joint (synchronised, so the robot stays exactly
on the segment that the motion planner validated), as fast as the joint
velocity and acceleration limits allow. The durations are rounded up to whole
periods so the output is sampled at a uniform ``dt`` (5 ms) with every segment
boundary on a sample; stretching a profile in time only lowers its velocities
and accelerations, so the limits hold for the finite differences of the
samples too (a finite difference averages the continuous profile).

A static margin is not enough at execution speed: a heavy object swung fast
moves the ZMP. With an evaluator, the ZMP of the cart-table model,
``zmp = c_xy - (c_z / g) c_xy''`` (CoM acceleration by central finite differences
at ``dt``, as the plan checker computes it), must keep ``zmp_min_margin_m``
inside the support polygon; segments where it does not are slowed down (time
scaled by ``slowdown_factor``; accelerations fall with its square) and the path
is timed again. The samples and the midpoints between successive samples are
also checked against the static margin threshold (the dense check).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.robot.model import RobotModel
from planner.stability.evaluator import HoldSpec, StateEvaluator

GRAVITY = 9.81
#: Waypoints closer than this (rad, per joint) are merged.
SAME_WAYPOINT_RAD = 1e-12
#: The contract's tolerance on the margin between points.
MARGIN_TOLERANCE_M = 1e-4
#: Extra time stretch on top of the computed one, since finite differences only approximate c''.
ZMP_SCALE_SLACK = 1.1


class TimingSettings(BaseModel):
    """Sampling period, how much of the limits to use, and the ZMP requirement."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    dt_s: float = Field(0.005, gt=0, description="uniform output period")
    velocity_scale: float = Field(0.95, gt=0, le=1, description="share of the URDF velocity limits used")
    acceleration_scale: float = Field(0.95, gt=0, le=1, description="share of the spec's acceleration limits used")
    zmp_min_margin_m: float = Field(0.005, ge=0, description="ZMP distance to keep inside the polygon edge")
    slowdown_factor: float = Field(1.3, gt=1, description="time scale applied to a segment whose ZMP leaves the margin")
    max_slowdowns: int = Field(20, ge=0, description="slow-down rounds before giving up")
    rest_samples: int = Field(1, ge=0, description="extra copies of the first and last sample (exactly zero velocity)")


@dataclass
class TimedPath:
    """Uniformly sampled trajectory: ``t`` (M,), ``Q`` (M, n), plus what the checks saw."""

    t: np.ndarray
    Q: np.ndarray
    segment_durations: np.ndarray
    ok: bool
    reason: str | None = None
    com: np.ndarray | None = None
    zmp: np.ndarray | None = None
    margin: np.ndarray | None = None
    zmp_margin: np.ndarray | None = None
    min_margin_m: float = math.nan
    min_zmp_margin_m: float = math.nan
    slowdowns: int = 0
    stats: dict = field(default_factory=dict)


def _clean(waypoints: np.ndarray) -> np.ndarray:
    W = np.atleast_2d(np.asarray(waypoints, dtype=float))
    if W.ndim != 2 or len(W) == 0:
        raise ValueError(f"waypoints must be an (K, n) array with K >= 1, got shape {W.shape}")
    if not np.all(np.isfinite(W)):
        raise ValueError("waypoints contain NaN or Inf")
    keep = [0]
    for i in range(1, len(W)):
        if np.abs(W[i] - W[keep[-1]]).max() > SAME_WAYPOINT_RAD:
            keep.append(i)
    return W[keep]


def _unit_profile(V: float, A: float) -> tuple[float, float]:
    """Duration and acceleration time of a rest-to-rest trapezoid covering s in [0, 1] with |s'| <= V, |s''| <= A."""
    if V * V / A >= 1.0:  # triangle: the peak speed is never reached
        ta = math.sqrt(1.0 / A)
        return 2.0 * ta, ta
    ta = V / A
    return 1.0 / V + ta, ta


def _sample_unit(times: np.ndarray, T: float, V: float, A: float, stretch: float) -> np.ndarray:
    """s(t) of the trapezoid (V, A) stretched in time by ``stretch``, at times in [0, T * stretch]."""
    u = times / stretch
    _, ta = _unit_profile(V, A)
    vpk = A * ta
    s = np.empty_like(u)
    a = u <= ta
    s[a] = 0.5 * A * u[a] ** 2
    d = u >= T - ta
    s[d] = 1.0 - 0.5 * A * (T - u[d]) ** 2
    c = ~(a | d)
    s[c] = 0.5 * A * ta**2 + vpk * (u[c] - ta)
    return np.clip(s, 0.0, 1.0)


def segment_profiles(W: np.ndarray, robot: RobotModel, settings: TimingSettings) -> list[tuple[float, float, float]]:
    """Per segment (T, V, A): the fastest synchronised unit trapezoid within the scaled limits."""
    vmax = robot.velocity_limit * settings.velocity_scale
    amax = robot.acceleration_limit * settings.acceleration_scale
    out = []
    for a, b in zip(W[:-1], W[1:]):
        D = np.abs(b - a)
        moving = D > 0
        V = float(np.min(vmax[moving] / D[moving]))
        A = float(np.min(amax[moving] / D[moving]))
        T, _ = _unit_profile(V, A)
        out.append((T, V, A))
    return out


def _sample(W: np.ndarray, profiles: list[tuple[float, float, float]], scales: np.ndarray, dt: float, rest: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples of every segment (boundaries shared), the durations and the segment index of each sample."""
    parts = [W[:1]]
    seg_of = [np.array([0])]
    durations = np.empty(len(profiles))
    for i, ((T, V, A), k) in enumerate(zip(profiles, scales)):
        n = max(1, int(math.ceil(T * k / dt - 1e-9)))
        stretch = n * dt / T
        durations[i] = n * dt
        s = _sample_unit(np.arange(1, n + 1) * dt, T, V, A, stretch)
        s[-1] = 1.0
        parts.append(W[i] + s[:, None] * (W[i + 1] - W[i]))
        seg_of.append(np.full(n, i))
    Q = np.vstack(parts)
    seg = np.concatenate(seg_of)
    if rest > 0:
        Q = np.vstack([np.repeat(Q[:1], rest, axis=0), Q, np.repeat(Q[-1:], rest, axis=0)])
        seg = np.concatenate([np.zeros(rest, int), seg, np.full(rest, seg[-1])])
    t = np.arange(len(Q)) * dt
    return t, Q, durations, seg


def zmp_cart_table(com: np.ndarray, dt: float, holding: list[str] | None = None) -> np.ndarray:
    """ZMP (M, 2) of the cart-table model: c_xy - (c_z / g) * c_xy'', with c'' by central finite
    differences at ``dt`` and zero at the two ends.

    Where ``holding`` changes, the system's mass changes and its CoM steps (the
    object's weight moves from the table to the hand); that step is not an
    acceleration of the robot. The plan is at rest there (every piece starts and ends
    at rest), so c'' is taken as zero at such points too.
    """
    acc = np.zeros((len(com), 2))
    if len(com) >= 3:
        acc[1:-1] = (com[2:, :2] - 2.0 * com[1:-1, :2] + com[:-2, :2]) / (dt * dt)
    if holding is not None and len(holding) >= 2:
        h = np.asarray(holding)
        change = np.flatnonzero(h[1:] != h[:-1])  # holding differs between i and i+1
        acc[np.clip(change, 0, len(acc) - 1)] = 0.0
        acc[np.clip(change + 1, 0, len(acc) - 1)] = 0.0
    return com[:, :2] - (com[:, 2:3] / GRAVITY) * acc


def time_parameterize(waypoints: np.ndarray, robot: RobotModel, settings: TimingSettings | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Kinematic timing only: ``t`` (M,), ``Q`` (M, n) within the velocity and acceleration limits, rest to rest."""
    s = settings or TimingSettings()
    W = _clean(waypoints)
    if len(W) == 1:
        Q = np.repeat(W, 1 + 2 * s.rest_samples, axis=0)
        return np.arange(len(Q)) * s.dt_s, Q
    profiles = segment_profiles(W, robot, s)
    t, Q, _, _ = _sample(W, profiles, np.ones(len(profiles)), s.dt_s, s.rest_samples)
    return t, Q


def time_path(
    waypoints: np.ndarray,
    robot: RobotModel,
    evaluator: StateEvaluator | None = None,
    hold: HoldSpec | None = None,
    settings: TimingSettings | None = None,
    threshold_m: float | None = None,
) -> TimedPath:
    """Time a path and, with an evaluator, keep the ZMP inside the polygon and check the margin densely.

    ``hold`` is what the hands hold along the whole path (one motion piece).
    ``threshold_m`` (default: the evaluator's) is what the dense check holds
    the samples and the midpoints between them to. ``ok`` is False with a
    ``reason`` when the ZMP cannot be kept in after ``max_slowdowns`` rounds or
    the dense check fails; the timed samples are returned either way.
    """
    s = settings or TimingSettings()
    W = _clean(waypoints)
    dt = s.dt_s
    if len(W) == 1:
        t, Q = time_parameterize(W, robot, s)
        return _finish(TimedPath(t=t, Q=Q, segment_durations=np.zeros(0), ok=True), evaluator, hold, threshold_m, dt, s, np.zeros(len(Q), int))
    profiles = segment_profiles(W, robot, s)
    scales = np.ones(len(profiles))
    slowdowns = 0
    while True:
        t, Q, durations, seg = _sample(W, profiles, scales, dt, s.rest_samples)
        result = TimedPath(t=t, Q=Q, segment_durations=durations, ok=True, slowdowns=slowdowns)
        if evaluator is None:
            return result
        result = _finish(result, evaluator, hold, threshold_m, dt, s, seg)
        if result.stats.get("zmp_ok", True):
            return result
        if slowdowns >= s.max_slowdowns:
            result.ok = False
            result.reason = (
                f"the ZMP leaves the {s.zmp_min_margin_m * 1000:.1f} mm margin (worst {result.min_zmp_margin_m * 1000:.1f} mm) "
                f"even after {slowdowns} slow-downs"
            )
            return result
        # Stretching a segment's time by k divides its CoM accelerations by k^2, and the
        # ZMP margin is at least the static margin minus |zmp - com|: scale each bad segment
        # so that its ZMP offset fits inside its own static margin.
        offset = np.linalg.norm(result.zmp - result.com[:, :2], axis=1)
        need = result.stats["zmp_required_m"]
        for j in np.unique(result.stats["zmp_bad_segments"]):
            in_seg = seg == j
            room = float(result.margin[in_seg].min()) - need
            if room <= 0.0:
                result.ok = False
                result.reason = f"segment {j} has only {room + need:.4f} m static margin; no speed keeps the ZMP {need * 1000:.1f} mm inside"
                return result
            ratio = float(offset[in_seg].max()) / room
            scales[j] *= max(s.slowdown_factor, math.sqrt(ratio) * ZMP_SCALE_SLACK)
        slowdowns += 1


def _finish(result: TimedPath, evaluator: StateEvaluator | None, hold: HoldSpec | None, threshold_m: float | None, dt: float, s: TimingSettings, seg: np.ndarray) -> TimedPath:
    """Fill CoM, ZMP and margins; decide the ZMP and dense checks."""
    if evaluator is None:
        return result
    Q = result.Q
    thr = evaluator.threshold_m if threshold_m is None else threshold_m
    batch = evaluator.evaluate(Q, hold)
    com = batch.com
    zmp = zmp_cart_table(com, dt)
    zmp_margin = evaluator.polygon.margin(zmp)
    # The ZMP requirement never asks more than the path's own static margin allows at rest.
    need = min(s.zmp_min_margin_m, max(0.0, 0.5 * float(batch.margin.min())))
    bad = zmp_margin < need
    result.com, result.zmp, result.margin, result.zmp_margin = com, zmp, batch.margin, zmp_margin
    result.min_zmp_margin_m = float(zmp_margin.min())
    result.stats["zmp_required_m"] = need
    result.stats["zmp_ok"] = not bad.any()
    # A central difference spans its neighbours: slow the segments of the samples around each bad one.
    idx = np.flatnonzero(bad)
    around = np.clip(np.concatenate([idx - 1, idx, idx + 1]), 0, len(seg) - 1)
    result.stats["zmp_bad_segments"] = seg[around]
    # Dense check: every sample and the midpoint between successive samples.
    if len(Q) >= 2:
        mids = 0.5 * (Q[1:] + Q[:-1])
        mid_margin = evaluator.evaluate(mids, hold).margin
        min_margin = float(min(batch.margin.min(), mid_margin.min()))
    else:
        min_margin = float(batch.margin.min())
    result.min_margin_m = min_margin
    if min_margin < thr - MARGIN_TOLERANCE_M:
        result.ok = False
        result.reason = f"the margin dips to {min_margin * 1000:.2f} mm between samples, below the {thr * 1000:.1f} mm threshold"
    return result
