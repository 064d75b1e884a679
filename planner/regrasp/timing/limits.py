"""What limits one run's timing: the rows TOPP-RA keeps along the path (the cart-table and multibody ZMP inside the
support polygon by the run's floor, the static plus inertial torques within the effort limits, gentler starts and
stops), the ZMP floor with its reserve and cap, and the time stretch the timed samples need to keep the limits as the
plan checker sees them (finite differences)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.array_keys import array_digest, array_key
from planner.motion.timing import zmp_cart_table
from planner.motion.topp import GRAVITY, BlendedPath, LinearRows, ZmpRows, zmp_rows
from planner.regrasp.timing.runs import Run
from planner.stability.com_path import com_path_terms
from planner.stability.inertial_torques import InertialTorques


@dataclass(frozen=True)
class PathGeometry:
    """A path's terms at its TOPP-RA gridpoints that no ZMP floor changes (:meth:`RunLimits._geometry`)."""

    static_margin: np.ndarray
    zmp: ZmpRows
    along: tuple[np.ndarray, np.ndarray] | None
    torques: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None


def _grasp_key(run: Run) -> tuple | None:
    """What the run's hand holds, as a lookup key: the TCP's side and the object's pose in it (None: nothing held)."""
    return None if run.hold is None else (run.hold.tcp_side, *array_key(run.hold.T_tcp_obj))


class RunLimits:
    """The limits of a run's timing, a part of :class:`planner.regrasp.timing.plan_timer.PlanTimer`: it uses the
    timer's ``task``, ``s`` (the settings), ``limits``, ``vlim``, ``alim``, ``dt``, ``zmp_margin_m``,
    ``reserve_share``, ``local_share``, ``plan_static_min_m``, ``_inertials``, ``_geometries`` and ``_asked``."""

    def _rows(self, run: Run, path: BlendedPath, grid: np.ndarray) -> tuple[list[LinearRows], float]:
        """TOPP-RA's rows at the gridpoints (the ZMP, cart-table and multibody, its step where the path's acceleration
        switches, and the torques) and the run's ZMP floor (:meth:`_zmp_floor`) they keep."""
        g = self._geometry(run, path, grid)
        polygon = self.task.evaluator.polygon
        floor_m = self._zmp_floor(g.static_margin)
        need = self._zmp_need(g.static_margin, floor_m, self.s.zmp_inner_m)
        z = g.zmp
        room = z.room - need[:, None]
        rows = [LinearRows(grid, z.a, z.b, np.zeros_like(z.a), np.full_like(room, -np.inf), np.maximum(room, 0.0))]
        if self.s.zmp_step_m > 0.0:  # where s_ddot switches, the ZMP steps by at most zmp_step_m along each normal
            half = np.full_like(z.a, 0.5 * self.s.zmp_step_m)
            rows.append(LinearRows(grid, z.a, np.zeros_like(z.b), np.zeros_like(z.a), -half, half))
        if self.s.zmp_angular_momentum:
            rows.append(self._multibody_zmp(run, g.along, grid, polygon, need, room))
        if g.torques is not None:
            A, B, tau_s, lim = g.torques
            rows.append(LinearRows(grid, A, B, tau_s, np.minimum(-lim, tau_s), np.maximum(lim, tau_s)))
        return rows, floor_m

    def _geometry(self, run: Run, path: BlendedPath, grid: np.ndarray) -> PathGeometry:
        """What the rows need of the path at the gridpoints and nothing of the ZMP floor: the CoM terms, the static
        margins, the cart-table ZMP's coefficients, the inertial sweep, the torques' rows. Kept by the path's points
        and what the run holds within one :meth:`time_plan` (``_geometries``), so that the reserve cap's second
        timing of a run, and a ranked path timed again as a run, solve TOPP-RA again without recomputing them: the
        same numbers, so the same rows. A plan keeps some 10-20 MB of them until it is timed."""
        P0, P1, P2 = path(grid, 0), path(grid, 1), path(grid, 2)
        key = (run.holding, _grasp_key(run), array_digest(grid, P0, P1, P2))  # a digest: the arrays weigh megabytes
        kept = self._geometries.get(key)
        if kept is not None:
            return kept
        t = self.task
        terms = com_path_terms(t.evaluator, P0, P1, P2, run.hold)
        polygon = t.evaluator.polygon
        along = (self._inertial(run).along_path(P0, P1, P2)
                 if self.s.zmp_angular_momentum or self.limits is not None else None)
        torques = None
        if self.limits is not None:
            tau_s = self._static(run, P0)
            A, B = self._inertial(run).coefficients(along)
            lim = self.limits.table.limit * self.s.effort_scale
            moved = (np.abs(A) + np.abs(B)).max(axis=0) > 1e-9  # the joints this motion loads at all
            if moved.any():
                torques = (A[:, moved], B[:, moved], tau_s[:, moved], lim[moved])
        geometry = self._geometries[key] = PathGeometry(
            static_margin=polygon.margin(terms.com[:, :2]),
            zmp=zmp_rows(terms.com, terms.d1, terms.d2, polygon.normals, polygon.offsets, 0.0),
            along=along, torques=torques)
        z = geometry.zmp
        for a in (geometry.static_margin, z.a, z.b, z.room, *(along or ()), *(torques or ())):
            a.flags.writeable = False  # handed to every timing that asks: a write into one would change them all
        return geometry

    def _zmp_floor(self, static_margin: np.ndarray) -> float:
        """How far inside the polygon a run keeps its ZMP, given the static CoM margins along its path: the ZMP
        margin, or the reserve's share (``reserve_share``: more on one foot) of the smallest of those margins where
        that is more. A fast swing's ZMP steps set the body swaying, and the feet then feel more than the planned
        ZMP; keeping the ZMP close to where the CoM is at its tightest leaves that sway the rest of the margin. With
        ``zmp_reserve_cap_share`` and the plan's smallest static margin known (:meth:`time_plan`), the reserve asks
        at most that share of it plus ``zmp_overshoot_m``."""
        tightest = float(np.maximum(static_margin, 0.0).min()) if static_margin.size else 0.0
        reserve = self.reserve_share * tightest
        if self._asked is not None:
            self._asked.append(reserve)
        return max(self.zmp_margin_m, min(reserve, self._reserve_cap()))

    def _reserve_cap(self) -> float:
        """The most the ZMP reserve may ask (:meth:`_zmp_floor`): infinite until the plan's smallest static margin
        is known, or without ``zmp_reserve_cap_share``."""
        if self.plan_static_min_m is None or self.s.zmp_reserve_cap_share is None:
            return math.inf
        return self.s.zmp_reserve_cap_share * self.plan_static_min_m + self.s.zmp_overshoot_m

    def _zmp_need(self, static_margin: np.ndarray, floor_m: float, inner_m: float = 0.0) -> np.ndarray:
        """How far inside every edge the ZMP must stay at points whose CoM is ``static_margin`` inside: the run's
        floor; where the CoM is closer than that, as far inside as the CoM. On one foot (``local_share``) also that
        share of the CoM's own margin at each point, up to the reserve's cap: the floor bounds where the ZMP may go
        at the run's tightest point, this how far ahead of the CoM it may step anywhere, so the body brakes before
        its CoM nears the edge. ``inner_m`` more inside, as far as the CoM (TOPP-RA's rows: room for the finite
        differences between gridpoints)."""
        inside = np.maximum(static_margin, 0.0)
        need = np.minimum(floor_m + inner_m, inside)
        local = self.local_share
        if local <= 0.0 or not inside.size:
            return need
        if self._asked is not None:  # what the cap may change (PlanTimer._once)
            self._asked.append(local * float(inside.max()))
        local_need = np.minimum(local * inside, self._reserve_cap()) + inner_m
        return np.maximum(need, np.minimum(local_need, inside))

    def _multibody_zmp(self, run: Run, along, grid, polygon, need, room) -> LinearRows:
        """The ZMP of the whole body, the rate of its angular momentum included, at least ``need`` inside every
        edge: with ``P_dot, L_dot`` (world, about the origin) from :meth:`InertialTorques.momentum_rate`, the ZMP is
        ``(M g c_xy + (-L_dot_y, L_dot_x)) / (M g + P_dot_z)``, so ``n.zmp >= offset + need`` is the row
        ``n_x L_dot_y - n_y L_dot_x + (offset + need) P_dot_z <= M g (n.c - offset - need)``. At rest it is the
        CoM's; a fast arm swing moves it where the cart-table model does not see it."""
        inert = self._inertial(run)
        A, B = inert.momentum_rate(along)
        nx, ny = polygon.normals[:, 0][None], polygon.normals[:, 1][None]
        shift = polygon.offsets[None] + need[:, None]
        a = nx * A[:, 4:5] - ny * A[:, 3:4] + shift * A[:, 2:3]
        b = nx * B[:, 4:5] - ny * B[:, 3:4] + shift * B[:, 2:3]
        weight = inert.total_mass * GRAVITY
        return LinearRows(grid, a, b, np.zeros_like(a), np.full_like(a, -np.inf), weight * np.maximum(room, 0.0))

    def _static(self, run: Run, Q: np.ndarray) -> np.ndarray:
        T_tcp_obj = None if run.hold is None else run.hold.T_tcp_obj
        return self.limits.evaluate(Q, run.holding, T_tcp_obj=T_tcp_obj).torque

    def _inertial(self, run: Run) -> InertialTorques:
        """The inertial torques of the robot holding what the run holds: one model per grasp, built once per plan."""
        t = self.task
        key = _grasp_key(run)
        if key not in self._inertials:
            if run.hold is None:
                self._inertials[key] = InertialTorques(t.robot, t.stance.base_pose)
            else:
                tcp = t.robot.spec.arms[run.hold.tcp_side].tcp
                self._inertials[key] = InertialTorques(t.robot, t.stance.base_pose, t.obj.mass_kg, tcp,
                                                       run.hold.T_tcp_obj, t.obj.com_local)
        return self._inertials[key]

    def _soft_ends(self, path: BlendedPath, grid: np.ndarray, cols: np.ndarray) -> LinearRows:
        """Joint acceleration rows whose limit rises linearly from ``end_acceleration_scale`` of the limit at a
        rest to all of it ``end_zone_rad`` (path length) away: gentler starts and stops, which set off the
        whole-body sway, at little cost in time (the middle of a motion keeps the full limit)."""
        to_rest = np.minimum(grid, path.length - grid)
        e = self.s.end_acceleration_scale
        share = e + (1.0 - e) * np.clip(to_rest / self.s.end_zone_rad, 0.0, 1.0)
        lim = share[:, None] * (self.alim[cols] * self.s.acceleration_scale)[None, :]
        a, b = path(grid, 1)[:, cols], path(grid, 2)[:, cols]
        return LinearRows(grid, a, b, np.zeros_like(a), -lim, lim)

    def _stretch_needed(self, run: Run, Q: np.ndarray, com: np.ndarray, need_at: np.ndarray) -> float:
        """The time stretch (>= 1) the samples Q (their system CoM ``com``) need to keep the limits as the checker
        sees them; 1 when they do."""
        dt = self.dt
        k = 1.0
        if len(Q) >= 2:
            v = np.abs(np.diff(Q, axis=0)) / dt
            k = max(k, float((v / self.vlim).max()))
        if len(Q) >= 3:
            a = np.abs(Q[2:] - 2.0 * Q[1:-1] + Q[:-2]) / (dt * dt)
            k = max(k, math.sqrt(float((a / self.alim).max())))
        t = self.task
        zmp = zmp_cart_table(com, dt)
        zm = t.evaluator.polygon.margin(zmp)
        bad = zm < need_at - 1e-9
        if bad.any():
            room = t.evaluator.polygon.margin(com[:, :2]) - need_at
            offset = np.linalg.norm(zmp - com[:, :2], axis=1)
            ratio = offset[bad] / np.maximum(room[bad], 1e-6)
            k = max(k, math.sqrt(float(ratio.max())) * 1.05, 1.05)
        if self.limits is not None and len(Q) >= 3:
            tau_s = self._static(run, Q)
            inert = self._inertial(run)
            dq = np.zeros_like(Q)
            ddq = np.zeros_like(Q)
            dq[1:-1] = (Q[2:] - Q[:-2]) / (2.0 * dt)
            ddq[1:-1] = (Q[2:] - 2.0 * Q[1:-1] + Q[:-2]) / (dt * dt)
            tau_d = inert.torques(Q, dq, ddq)  # M(q) q'' + C(q, q') q'
            lim = self.limits.table.limit
            over = np.abs(tau_s + tau_d) > lim
            if over.any():
                room = np.maximum(lim - np.abs(tau_s), 1e-9)
                k = max(k, math.sqrt(float((np.abs(tau_d) / room)[over].max())) * 1.02)
        return k
