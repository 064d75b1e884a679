"""Time-optimal path parameterization (TOPP-RA) of a blended joint path, with balance constraints.

The path: the straight segments between waypoints that the planner validated, with each
interior corner replaced by a quadratic blend (a parabola tangent to both segments, ``d`` before
and after the corner), parameterized by arc length in joint space. It is C1 (unit speed on the
lines and at the blend ends) and piecewise C2, which is what TOPP-RA's second-order constraints
need; a corner with ``d = 0`` is a stop and splits the path there. A blend stays within
``d / 2`` of its corner, inside the box of the joint limits (a convex set holding the segments).

The timing: TOPP-RA (``toppra``, Pham and Pham 2018) finds the fastest ``s_dot(s)`` from rest to
rest within constraints that are linear in ``(s_ddot, s_dot^2)`` at each gridpoint:

- joint velocity and acceleration limits;
- static plus inertial joint torques within the effort limits (rows given by the caller);
- the cart-table ZMP ``c_xy - (c_z / g) c_xy_ddot`` at least a margin inside every edge of the
  support polygon (rows given by the caller; :func:`zmp_rows`).

:func:`sample` then turns ``s_dot(s)`` (constant ``s_ddot`` between gridpoints) into samples at a
uniform period, stretched in time to a whole number of periods and by ``1 / speed_scale``.
Stretching time by ``k`` scales velocities by ``1/k`` and accelerations by ``1/k^2``, and moves the
ZMP towards the CoM along a straight line, so every constraint that held still holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint
from toppra.constraint import DiscretizationType
from toppra.constraint.linear_constraint import canlinear_colloc_to_interpolate
from scipy.interpolate import BSpline
from toppra.interpolator import AbstractGeometricPath

GRAVITY = 9.81


class _JointPath(AbstractGeometricPath):
    """What TOPP-RA asks of a joint path besides its values: its dimension and the path parameter's interval
    ``[0, length]``."""

    _dof: int
    length: float

    @property
    def dof(self) -> int:
        return self._dof

    @property
    def path_interval(self) -> np.ndarray:
        return np.array([0.0, self.length])


class BlendedPath(_JointPath):
    """Straight segments through ``waypoints`` (K, n) with quadratic corner blends of half-length
    ``blends[i]`` at interior waypoint ``i + 1`` (K - 2,).

    ``fill=False``: each blend clipped to half of each neighbouring segment. ``fill=True``: a segment's two blends
    get what they ask for when it fits, else each at least its share of it and the one asking less all it asks (a
    segment may be all blend). The shares are in proportion to how sharply the two corners turn (``|u_out - u_in|``):
    a corner's top speed goes as the square root of its blend over its turn, so a sharp corner beside a gentle one
    takes most of the short segment between them, and the slower of the two gets faster. A blend next to the path's
    first or last segment may take all of it (nothing else blends there): a short segment between two corners, as
    shortcuts leave them, then limits its corners far less, and the path keeps more speed through them."""

    def __init__(self, waypoints: np.ndarray, blends: np.ndarray, fill: bool = False):
        W = np.asarray(waypoints, dtype=float)
        if len(W) < 2:
            raise ValueError("a path needs two waypoints at least")
        seg = np.diff(W, axis=0)
        length = np.linalg.norm(seg, axis=1)
        if np.any(length <= 0.0):
            raise ValueError("consecutive waypoints must differ")
        unit = seg / length[:, None]
        d = np.zeros(len(W))
        if len(W) > 2:
            b = np.maximum(np.asarray(blends, dtype=float), 0.0)
            if fill:
                d[1:-1] = np.minimum(b, np.minimum(length[:-1], length[1:]))
                turn = np.zeros(len(W))  # how sharp each corner is: |u_out - u_in| (0 at the path's ends)
                turn[1:-1] = np.linalg.norm(unit[1:] - unit[:-1], axis=1)
                for j in range(len(length)):  # each segment: its two blends within it (lowering one never breaks another)
                    if d[j] + d[j + 1] <= length[j]:
                        continue
                    both = turn[j] + turn[j + 1]
                    share = length[j] * (turn[j] / both if both > 0.0 else 0.5)  # the first corner's share
                    if d[j] < share:
                        d[j + 1] = length[j] - d[j]
                    elif d[j + 1] < length[j] - share:
                        d[j] = length[j] - d[j + 1]
                    else:
                        d[j], d[j + 1] = share, length[j] - share
            else:
                d[1:-1] = np.minimum(b, 0.5 * np.minimum(length[:-1], length[1:]))
        self.blend = d[1:-1].copy()
        starts, c0, c1, c2 = [], [], [], []
        s = 0.0
        self.waypoint_s = np.zeros(len(W))
        for i in range(len(W) - 1):
            a = W[i] + d[i] * unit[i]
            line = length[i] - d[i] - d[i + 1]
            if line > 1e-12 * length[i]:  # a segment that its blends take whole, to rounding, has no line left
                starts.append(s); c0.append(a); c1.append(unit[i]); c2.append(np.zeros(W.shape[1]))
                s += line
            if i + 1 < len(W) - 1 and d[i + 1] > 0.0:
                h = 2.0 * d[i + 1]
                starts.append(s); c0.append(W[i + 1] - d[i + 1] * unit[i]); c1.append(unit[i])
                c2.append((unit[i + 1] - unit[i]) / (4.0 * d[i + 1]))
                self.waypoint_s[i + 1] = s + 0.5 * h
                s += h
            else:
                self.waypoint_s[i + 1] = s
        self.waypoint_s[-1] = s
        self.breaks = np.array(starts + [s])
        self.c0, self.c1, self.c2 = np.array(c0), np.array(c1), np.array(c2)
        self.length = s
        self._dof = W.shape[1]

    def __call__(self, path_positions, order: int = 0) -> np.ndarray:
        ss = np.atleast_1d(np.asarray(path_positions, dtype=float))
        k = np.clip(np.searchsorted(self.breaks, ss, side="right") - 1, 0, len(self.c0) - 1)
        tau = (ss - self.breaks[k])[:, None]
        if order == 0:
            out = self.c0[k] + self.c1[k] * tau + self.c2[k] * tau * tau
        elif order == 1:
            out = self.c1[k] + 2.0 * self.c2[k] * tau
        elif order == 2:
            out = 2.0 * self.c2[k]
        else:
            out = np.zeros((len(ss), self._dof))
        return out[0] if np.ndim(path_positions) == 0 else out


class SplinePath(_JointPath):
    """A clamped cubic B-spline with the waypoints (K, n) as its control points: it starts at the first and ends at
    the last waypoint, tangent to the first and last legs, and passes near (not through) the interior ones, inside
    the convex hull of each four consecutive waypoints. C2 everywhere, so its curvature is spread along the whole
    path instead of packed into a blend at each corner: a run of short segments and corners, as shortcuts leave them,
    can be followed much faster. It strays farther from the waypoints than blends do, so it is only used where the
    checks of its own states pass.

    The knots are placed by chord length (averaged, de Boor); the path parameter is ``s = u L`` with ``u`` in [0, 1]
    and ``L`` the spline's arc length, so its speed averages one. ``waypoint_s``: each waypoint's Greville abscissa
    (where its basis function peaks, the path position it pulls towards); ``blend``: zeros (no blend to shrink)."""

    def __init__(self, waypoints: np.ndarray, *, _knots: np.ndarray | None = None, _length: float | None = None):
        W = np.asarray(waypoints, dtype=float)
        if len(W) < 2:
            raise ValueError("a path needs two waypoints at least")
        k = min(3, len(W) - 1)
        if _knots is None:
            chord = np.linalg.norm(np.diff(W, axis=0), axis=1)
            if np.any(chord <= 0.0):
                raise ValueError("consecutive waypoints must differ")
            u = np.r_[0.0, np.cumsum(chord)] / chord.sum()
            inner = [float(np.mean(u[i:i + k])) for i in range(1, len(W) - k)]
            _knots = np.r_[np.zeros(k + 1), inner, np.ones(k + 1)]
        self.knots = _knots
        self._spline = BSpline(_knots, W, k)
        if _length is None:
            uu = np.linspace(0.0, 1.0, 64 * len(W) + 1)
            speed = np.linalg.norm(self._spline(uu, 1), axis=1)
            _length = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(uu)))
        self.length = _length
        self.breaks = np.array([0.0, _length])
        self.waypoint_s = np.array([float(np.mean(_knots[i + 1:i + k + 1])) for i in range(len(W))]) * _length
        self.blend = np.zeros(max(len(W) - 2, 0))
        self._dof = W.shape[1]

    def columns(self, cols: np.ndarray) -> "SplinePath":
        """The same path over joints ``cols`` only: the same knots and parameter."""
        return SplinePath(self._spline.c[:, cols], _knots=self.knots, _length=self.length)

    def __call__(self, path_positions, order: int = 0) -> np.ndarray:
        ss = np.atleast_1d(np.asarray(path_positions, dtype=float))
        u = np.clip(ss / self.length, 0.0, 1.0)
        out = self._spline(u, order) / self.length ** order
        return out[0] if np.ndim(path_positions) == 0 else out


class LinearRows(toppra.constraint.LinearConstraint):
    """Constraint rows ``lower <= a u + b x + c <= upper`` (u = s_ddot, x = s_dot^2) precomputed at the
    gridpoints; ``a``, ``b``, ``c``, ``lower``, ``upper`` are (N + 1, m). A bound infinite at every gridpoint (a
    one-sided row) adds no row; one infinite at some gridpoints only is refused.

    The rows are handed to TOPP-RA in its "identical" form, ``F (a' u + b' x + c') <= g`` with one ``F`` and ``g``
    for every gridpoint (``F`` the identity, ``g`` zero, the bounds folded into ``c'``): its seidel solver then sets
    up the rows with one matrix product instead of three products per gridpoint, which made the setup most of a
    short solve. The rows and their values are the same as ``F_i = [I; -I]``, ``g_i = [upper_i; -lower_i]``."""

    def __init__(self, gridpoints: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                 lower: np.ndarray, upper: np.ndarray):
        super().__init__()
        self.gridpoints = np.asarray(gridpoints)
        lower, upper = np.broadcast_to(lower, a.shape), np.broadcast_to(upper, a.shape)
        up = ~np.all(np.isposinf(upper), axis=0)  # the columns with an upper bound
        low = ~np.all(np.isneginf(lower), axis=0)
        if np.any(np.isinf(upper[:, up])) or np.any(np.isinf(lower[:, low])):  # (a NaN goes on, as TOPP-RA takes it)
            raise ValueError("a row's bound must be finite at every gridpoint or infinite at all of them")
        self.a = np.hstack([a[:, up], -a[:, low]])
        self.b = np.hstack([b[:, up], -b[:, low]])
        self.c = np.hstack([c[:, up] - upper[:, up], lower[:, low] - c[:, low]])
        k = self.a.shape[1]
        self.F, self.g = np.eye(k), np.zeros(k)
        self.identical = True
        self.set_discretization_type(DiscretizationType.Interpolation)

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        if len(gridpoints) != len(self.gridpoints) or np.abs(np.asarray(gridpoints) - self.gridpoints).max() > 0:
            raise ValueError("the rows were computed for other gridpoints")
        # interpolation: the rows of gridpoint i + 1 also hold with the s_ddot chosen at gridpoint i, so that
        # they hold at both ends of every interval, where the profile really is
        return canlinear_colloc_to_interpolate(self.a, self.b, self.c, self.F, self.g, None, None, gridpoints,
                                               identical=True)


class _JointVelocity(toppra.constraint.JointVelocityConstraint):
    """TOPP-RA's joint velocity limits (a bound on s_dot^2 at each gridpoint), checked without the per-joint text
    its own check formats for display, which cost more than the bound itself on a short path."""

    def _assert_valid_limits(self) -> None:
        if self.vlim.shape[1] != 2 or np.any(self.vlim[:, 0] >= self.vlim[:, 1]):
            raise ValueError("each joint's lower velocity limit must be below its upper one")
        self._format_string = f"    Velocity limit: {self.dof} joints\n"


@dataclass(frozen=True)
class ZmpRows:
    """At each gridpoint: per polygon edge, ``(c_z / g) n.c'`` (coefficient of s_ddot), ``(c_z / g) n.c''``
    (of s_dot^2), and the room ``n.c_xy - offset - margin`` they must stay below."""

    a: np.ndarray
    b: np.ndarray
    room: np.ndarray


def zmp_rows(com: np.ndarray, d1: np.ndarray, d2: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
             margin_m: float) -> ZmpRows:
    """The ZMP constraint of the cart-table model as rows linear in (s_ddot, s_dot^2).

    ``n.zmp - offset >= margin`` for every inward edge normal ``n`` with
    ``zmp = c_xy - (c_z / g)(c' s_ddot + c'' s_dot^2)`` reads
    ``(c_z / g)(n.c') s_ddot + (c_z / g)(n.c'') s_dot^2 <= n.c_xy - offset - margin``."""
    k = (com[:, 2] / GRAVITY)[:, None]
    a = k * (d1[:, :2] @ normals.T)
    b = k * (d2[:, :2] @ normals.T)
    room = com[:, :2] @ normals.T - offsets[None] - margin_m
    return ZmpRows(a=a, b=b, room=room)


#: Gridpoints on both sides of each break of the path, this far from it (share of the path's length): the path's
#: second derivative jumps there, and the constraints must hold with either value.
BREAK_SIDE = 1e-6


def gridpoints_for(path: BlendedPath, step: float, max_points: int) -> np.ndarray:
    """Uniform gridpoints of about ``step`` (at most ``max_points``), plus every break of the path and a point just
    before it (the constraints are evaluated with the path's derivatives on the side after a gridpoint)."""
    n = int(min(max(math.ceil(path.length / step), 2), max_points))
    eps = BREAK_SIDE * path.length
    inner = path.breaks[1:-1]
    grid = np.union1d(np.linspace(0.0, path.length, n + 1), np.concatenate([path.breaks, inner - eps]))
    grid = grid[(grid >= 0.0) & (grid <= path.length)]
    keep = np.r_[True, np.diff(grid) > 0.1 * eps]
    grid = grid[keep]
    grid[-1] = path.length
    return grid


def parameterize(path: BlendedPath, gridpoints: np.ndarray, vlim: np.ndarray, alim: np.ndarray,
                 rows: list[LinearRows]) -> np.ndarray | None:
    """The time-optimal ``s_dot`` at the gridpoints from rest to rest, or None when TOPP-RA finds none."""
    # the joint accelerations q' s_ddot + q'' s_dot^2 within +-alim: rows as the others are
    accelerations = LinearRows(gridpoints, path(gridpoints, 1), path(gridpoints, 2),
                               np.zeros((len(gridpoints), len(alim))), -alim, alim)
    constraints = [_JointVelocity(np.column_stack([-vlim, vlim])), accelerations, *rows]
    algo = toppra.algorithm.TOPPRA(constraints, path, gridpoints=gridpoints, solver_wrapper="seidel")
    algo.compute_parameterization(0.0, 0.0)
    sd = algo.problem_data.sd_vec
    if algo.problem_data.return_code != toppra.algorithm.ParameterizationReturnCode.Ok or sd is None or np.any(~np.isfinite(sd)):
        return None
    sd = np.abs(np.asarray(sd, dtype=float))
    if len(sd) > 2 and np.any(sd[1:-1] <= 0.0):  # the path cannot be followed without stopping inside it
        return None
    return sd


def profile_times(gridpoints: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """Time at each gridpoint when s_ddot is constant between gridpoints."""
    ds = np.diff(gridpoints)
    v = sd[:-1] + sd[1:]
    with np.errstate(divide="ignore"):
        dt = np.where(v > 0, 2.0 * ds / np.where(v > 0, v, 1.0), np.inf)
    return np.concatenate([[0.0], np.cumsum(dt)])


def s_at(times: np.ndarray, gridpoints: np.ndarray, sd: np.ndarray, t_grid: np.ndarray) -> np.ndarray:
    """The path position at ``times`` of the profile (constant s_ddot between gridpoints)."""
    k = np.clip(np.searchsorted(t_grid, times, side="right") - 1, 0, len(gridpoints) - 2)
    tau = np.clip(times - t_grid[k], 0.0, None)
    ds = gridpoints[k + 1] - gridpoints[k]
    acc = (sd[k + 1] ** 2 - sd[k] ** 2) / (2.0 * ds)
    s = gridpoints[k] + sd[k] * tau + 0.5 * acc * tau * tau
    return np.clip(np.minimum(s, gridpoints[k + 1]), 0.0, gridpoints[-1])


def sample(path: BlendedPath, gridpoints: np.ndarray, sd: np.ndarray, dt: float, stretch: float) -> tuple[np.ndarray, float, float]:
    """Samples ``s`` at the period ``dt`` of the profile stretched in time by at least ``stretch``
    (>= 1) and up to a whole number of periods; returns (s (M,), the profile's own duration, the
    duration sampled). The first sample is 0 and the last the path's end."""
    t_grid = profile_times(gridpoints, sd)
    T = float(t_grid[-1])
    n = max(1, int(math.ceil(T * stretch / dt - 1e-9)))
    u = np.arange(n + 1) * (T / n)
    s = s_at(u, gridpoints, sd, t_grid)
    s[0], s[-1] = 0.0, path.length
    return s, T, n * dt


def shaped(s: np.ndarray, window: int) -> np.ndarray:
    """The samples ``s`` (from rest to rest) through a moving average of ``window`` samples: a finite-impulse
    response filter that keeps the motion on the path (each value is a mean of path positions, and the
    sequence stays monotone) and bounds its jerk by the acceleration's change over the window; it adds
    ``window - 1`` samples. A window of one period of a mode leaves that mode no residual vibration at rest."""
    if window <= 1:
        return s
    padded = np.concatenate([np.full(window - 1, s[0]), s, np.full(window - 1, s[-1])])
    out = np.convolve(padded, np.full(window, 1.0 / window), mode="valid")
    out[0], out[-1] = s[0], s[-1]
    return out
