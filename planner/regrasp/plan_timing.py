"""Timing of a solved plan: blended through its waypoints, time-optimal under the robot's and the balance's limits.

The search validated every motion piece as straight segments between waypoints and timed each
rest to rest (:mod:`planner.motion.timing`). Here the plan is timed again as it will run:

1. **Runs.** Consecutive pieces form one run, traversed without stopping, unless the task needs
   rest between them: where what the hands hold changes (grasp, release, the handover's
   exchange) and around every move of a jaw. A run starts and ends at rest.
2. **Blends.** Each interior waypoint of a run is replaced by a quadratic blend
   (:class:`planner.motion.topp.BlendedPath`) of half-length up to ``blend_rad``, a segment's two blends sharing
   it as they need. The blended path is checked every ``path_check_rad`` before it is timed (the checks of
   item 5): its blends are shrunk, or the run refused, before TOPP-RA runs.
3. **Time-optimal timing** (TOPP-RA, :func:`planner.motion.topp.parameterize`) within the joint
   velocity and acceleration limits, the static plus inertial joint torques within the effort
   limits, and the cart-table ZMP at least ``zmp_margin_m`` inside the support polygon, or
   ``zmp_reserve_share`` of the run's smallest static CoM margin where that is more (where the
   CoM itself is closer to an edge than that, as far inside as the CoM). The CoM terms come from
   :mod:`planner.stability.com_path`, the torques from :mod:`planner.stability.effort` and
   :mod:`planner.stability.inertial_torques`. Then ``1 / speed_scale`` stretches it in time.
4. **Checks of the samples**, as the plan checker computes them: velocities and accelerations by
   finite differences, the ZMP by central differences, the static plus inertial torques; a run
   that exceeds one is stretched in time (which keeps it on the path and only lowers them) and
   sampled again.
5. **Validation again at the dense samples**: every sample through the task's state checker
   (collision, the margin, the static limits) with the grasping rules of the piece it belongs to,
   and the margin at the midpoints between samples. A blend with a failing sample is halved, at
   the last round removed (the robot then stops at that waypoint). A run that cannot be timed
   keeps the search's own rest-to-rest timing, which was validated.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Callable, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.motion.smoothing import SmoothingSettings, partial_shortcut, path_length, shortcut
from planner.motion.task_space_vias import ViaSettings, via_paths
from planner.motion.trrt import plan_motion
from planner.motion.timing import MARGIN_TOLERANCE_M, zmp_cart_table
from planner.motion.topp import (
    GRAVITY,
    BlendedPath,
    LinearRows,
    SplinePath,
    gridpoints_for,
    parameterize,
    profile_times,
    sample,
    shaped,
    zmp_rows,
)
from planner.forking import fork_is_safe, spare_cores
from planner.regrasp.fork_share import share_with_child
from planner.regrasp.concurrent_arms import LEADS, merged_pieces
from planner.regrasp.plan_assembly import MotionPiece, object_states
from planner.regrasp.state_checker import StateChecker
from planner.stability.com_path import com_path_terms
from planner.stability.effort import EffortEvaluator
from planner.stability.evaluator import HoldSpec
from planner.stability.inertial_torques import InertialTorques
from planner.termination import Termination

METHOD = "topp-ra"
#: The random stream of the timing's shortcuts (apart from the search's hop streams).
SHORTCUT_STREAM = 7919
#: Waypoints closer than this (rad, per joint) are one.
SAME_WAYPOINT_RAD = 1e-9


class PlanTimingSettings(BaseModel):
    """How the plan is timed: the share of the limits used, the blends, the TOPP-RA grid."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    velocity_scale: float = Field(0.98, gt=0, le=1, description="share of the URDF velocity limits TOPP-RA may use")
    acceleration_scale: float = Field(0.98, gt=0, le=1, description="share of the spec's acceleration limits TOPP-RA may use")
    effort_scale: float = Field(0.98, gt=0, le=1, description="share of the effort limits the static plus inertial torques may use")
    shortcut_iterations: int = Field(60, ge=0, description="random shortcuts tried on each of the shortened_paths "
                                     "quickest paths of each planned motion before they are ranked")
    replans: int = Field(4, ge=0, description="more T-RRT runs of each planned motion of the solved plan (own seeded "
                         "streams), each shortened by its own shortcuts; the quickest replaces the motion's own "
                         "path (one run's detour around the table often costs seconds)")
    partial_shortcut_iterations: int = Field(200, ge=0, description="partial shortcuts (one joint made linear "
                                             "between two points) of each of the shortened_paths quickest paths of "
                                             "each planned motion, after its random shortcuts and before the ranking")
    vias: ViaSettings = Field(default_factory=ViaSettings, description="paths through one or two task-space via "
                              "postures of the moving hand, added to each one-hand motion's replans (the quick way "
                              "around the table's edge that T-RRT seldom finds; keep 0: none)")
    alternatives: int = Field(4, ge=1, description="quickest paths of each planned motion kept, tried in order when "
                              "a quicker one fails the dense checks of its samples")
    replan_shortcut_iterations: int = Field(60, ge=0, description="random shortcuts of each replanned motion before "
                                            "the quickest are chosen (checked at the search's resolution, as the "
                                            "search checks its own)")
    shortened_paths: int = Field(3, ge=1, description="the quickest paths of each planned motion at the velocity "
                                 "limits (after each replan's own shortcuts) that get the full shortening "
                                 "(shortcut_iterations, then partial_shortcut_iterations) before the ranking")
    shortcut_check_rad: float = Field(0.005, gt=0, description="largest per-joint change between the checked states "
                                      "of the new segments the full shortening's shortcuts and partial shortcuts "
                                      "make (at most the search's resolution): a segment checked as coarsely as "
                                      "the search's can graze between its checked states, and the dense checks of "
                                      "the timed samples then refuse the path it belongs to")
    rank_by_timing: bool = Field(True, description="rank each planned motion's paths by their TOPP-RA time (blended, "
                                 "the same constraints, a coarse grid) rather than by the time at the velocity limits "
                                 "alone, which leaves out the corners and the balance")
    rank_grid_step_rad: float = Field(0.05, gt=0, description="TOPP-RA gridpoint spacing (rad) of that ranking")
    blend_rad: float = Field(0.5, ge=0, description="largest half-length of a corner blend (joint-space arc length, rad)")
    blend_fill: bool = Field(True, description="a segment's two corner blends share it as they need (each at least "
                             "half, the rest to the one that asks more; the path's first and last segments wholly to "
                             "their one blend) instead of half each")
    spline_runs: bool = Field(True, description="also time each run with a corner along the cubic B-spline of its "
                              "waypoints (curvature spread along the path, not packed into a blend at each corner), "
                              "checked as a blended run is; the quicker of the two that pass is kept")
    spline_rounds: int = Field(4, ge=0, description="times a spline whose states fail the checks is pulled towards "
                               "the corners nearest the failures (a midpoint on both their legs) and checked again")
    blend_rounds: int = Field(3, ge=0, description="times a blend with an invalid sample is halved before it is removed")
    grid_step_rad: float = Field(0.02, gt=0, description="TOPP-RA gridpoint spacing along the path (rad)")
    max_gridpoints: int = Field(400, ge=10, description="TOPP-RA gridpoints per run at most")
    zmp_reserve_share: float = Field(0.9, ge=0, le=1, description="the ZMP is kept at least this share of the "
                                     "run's smallest static CoM margin inside the polygon too (never less than "
                                     "zmp_margin_m; where the CoM itself is closer, as far as the CoM): the motion's "
                                     "own dynamics may take at most the rest of the margin the run has at its "
                                     "tightest. A user's own zmp_margin_m replaces it (0: the margin alone)")
    zmp_reserve_cap_share: float | None = Field(0.75, ge=0, le=1, description="the reserve asks at most this share "
                                                "of the plan's smallest static CoM margin (0.75: the physics twin's "
                                                "target for the CoP) plus zmp_overshoot_m, so a run with far more margin "
                                                "than the plan's tightest point keeps only that; where there is a "
                                                "reserve, the runs are timed twice (the first timing gives the plan's "
                                                "margin). None: no cap")
    zmp_overshoot_m: float = Field(0.019, ge=0, description="with zmp_reserve_cap_share: how far the centre of "
                                   "pressure may go past the planned ZMP where a bang-bang profile switches (13-19 mm "
                                   "in the physics twin with its stand-in stabilizer; a site fits it to its own)")
    zmp_inner_m: float = Field(0.0005, ge=0, description="extra ZMP margin inside TOPP-RA, for the finite differences between gridpoints")
    shaping_window_s: float = Field(0.0, ge=0, le=2.0, description="moving average of the path position over this "
                                    "time: jerk limited, starts and stops spread out (0: TOPP-RA's bang-bang profile)")
    trust_search_segments: bool = Field(False, description="skip the state checks of samples on the search's own "
                                        "straight segments (checked every 0.02 rad, so a graze between two checked "
                                        "states passes); off: every sample is checked")
    zmp_angular_momentum: bool = Field(True, description="keep the multibody ZMP (the rate of the body's angular "
                                       "momentum included) inside the margin too, not only the cart-table one")
    end_acceleration_scale: float = Field(1.0, gt=0, le=1, description="share of the acceleration limits at a rest "
                                          "(start, stop), rising to all of it end_zone_rad away: gentler starts and stops")
    end_zone_rad: float = Field(0.0, ge=0, description="path length (rad) over which the acceleration share rises "
                                "from end_acceleration_scale to 1 after a start and before a stop")
    path_check_rad: float = Field(0.01, ge=0, description="spacing (joint-space arc length, rad) of the states of a "
                                  "run's blended path checked before it is timed, so that blends are shrunk and failing "
                                  "alternatives refused without timing them first (0: only the timed samples are checked)")
    concurrent_arms: bool = Field(True, description="around a handover, also time each run with the two arms' "
                                  "consecutive motions that move different joints (the giver's carry and the taker's "
                                  "way to the handover; the giver's way home and the taker's carry) made one, both "
                                  "arms moving at once (planner/regrasp/concurrent_arms.py), and keep it where its "
                                  "samples pass; off: one arm after the other")
    check_rounds: int = Field(8, ge=1, description="time stretches of a run whose samples exceed a limit")
    rest_samples: int = Field(1, ge=0, description="extra copies of a run's first and last sample (exactly zero velocity)")


@dataclass
class Run:
    """Pieces traversed without stopping: their joint path and what is held along it."""

    pieces: list[MotionPiece]
    holding: Literal["none", "left", "right", "both"]
    hold: HoldSpec | None
    free_object: np.ndarray | None
    #: the search's own path of the run (its pieces' waypoints), whose straight segments the search validated
    validated: np.ndarray | None = None


@dataclass
class PlanTiming:
    """The retimed pieces and what the plan records of the timing."""

    pieces: list[MotionPiece]
    record: dict
    stats: dict = field(default_factory=dict)


def _jaw_moves(piece: MotionPiece, jaw_cols: np.ndarray) -> bool:
    P = piece.joint_path()
    return bool(jaw_cols.size and np.abs(P[-1, jaw_cols] - P[0, jaw_cols]).max() > 0.0)


def runs_of(pieces: list[MotionPiece], task) -> list[Run]:
    """Split the plan into runs: rest where the holding changes and around every jaw move."""
    jaw_cols = np.concatenate([np.asarray(v, dtype=int) for v in task.jaw.values()]) if task.jaw else np.zeros(0, int)
    runs: list[Run] = []
    prev_jaw = False
    for piece, holding, hold, current in object_states(pieces, task.evaluator, task.placements[task.start_id]):
        jaw = _jaw_moves(piece, jaw_cols)
        if runs and runs[-1].holding == holding and not jaw and not prev_jaw:
            runs[-1].pieces.append(piece)
        else:
            runs.append(Run([piece], holding, hold, None if hold is not None else current.copy()))
        prev_jaw = jaw
    return runs


def grasping_of(piece: MotionPiece, hold: HoldSpec | None) -> str | None:
    """The hand whose fingers touch the object by design along a piece, as the search checked it: the moving hand
    of an approach or a retreat; at a handover's jaw moves, the hand other than the one the object follows."""
    if piece.kind in ("approach", "retreat") and piece.hand in ("left", "right"):
        return piece.hand
    if piece.kind == "handover" and hold is not None:
        return "right" if hold.tcp_side == "left" else "left"
    return None


def off_path(Q: np.ndarray, W: np.ndarray | None, tol: float = 1e-7) -> np.ndarray:
    """Whether each state of Q (N, n) lies off the polyline W (K, n) (all of them when W is None)."""
    if W is None or len(W) < 2:
        return np.ones(len(Q), dtype=bool)
    a, d = W[:-1], np.diff(W, axis=0)  # (K-1, n)
    dd = np.maximum((d * d).sum(axis=1), 1e-300)
    off = np.ones(len(Q), dtype=bool)
    for start in range(0, len(Q), 256):
        q = Q[start:start + 256, None, :]
        t = np.clip(((q - a) * d).sum(axis=2) / dd, 0.0, 1.0)
        dist = np.abs(q - (a + t[..., None] * d)).max(axis=2).min(axis=1)
        off[start:start + 256] = dist > tol
    return off


def waypoints_of(run: Run) -> tuple[np.ndarray, list[int]]:
    """The run's waypoints (duplicates merged) and the index of the waypoint each piece starts at."""
    W: list[np.ndarray] = []
    starts = []
    for piece in run.pieces:
        P = piece.joint_path()
        starts.append(max(len(W) - 1, 0))
        for q in P:
            if not W or np.abs(q - W[-1]).max() > SAME_WAYPOINT_RAD:
                W.append(q)
    return np.array(W), starts


class PlanTimer:
    """Times the runs of one plan for one task."""

    def __init__(self, task, settings: PlanTimingSettings, speed_scale: float, zmp_margin_m: float, dt: float, *,
                 checker: StateChecker | None = None):
        """``checker``: the search's state checker (its counts go to the plan); a fresh one, on first use, when
        not given."""
        self.task = task
        self._checker = checker
        self.s = settings
        self.speed_scale = float(speed_scale)
        self.zmp_margin_m = float(zmp_margin_m)
        self.dt = float(dt)
        robot = task.robot
        self.vlim = robot.velocity_limit
        self.alim = robot.acceleration_limit
        self.limits: EffortEvaluator | None = task.limits
        self.threshold = task.evaluator.threshold_m if task.constrained else -np.inf
        self._inertials: dict = {}
        #: the timed plan's smallest static CoM margin, for the reserve's cap (set by :meth:`time_plan`)
        self.plan_static_min_m: float | None = None
        #: results kept within one :meth:`time_plan`, by key: the result, what it added to the stats, the uncapped ZMP
        #: reserves it asked with the cap of the day (:meth:`_once`)
        self._kept: dict = {}
        #: the uncapped ZMP reserves asked since the innermost :meth:`_once` began (None: nobody is listening)
        self._asked: list[float] | None = None
        #: the runs of one :meth:`time_plan` along their alternatives' paths, by run and paths (:meth:`_run_along`)
        self._along: dict = {}
        #: the runs of one :meth:`time_plan` timed early, while the helper worked (:meth:`_time_early`)
        self._early: set[int] = set()
        #: the runs of one :meth:`time_plan` with both arms at once, by run and lead (:meth:`_both_arms`)
        self._merged: dict = {}
        self.stats = {"merged_runs": 0, "merged_refused": 0, "shortened_s": 0.0, "alternatives_dropped": 0, "refused": [], "checked_samples": 0, "runs": 0, "blends": 0, "blends_removed": 0, "fallback_runs": 0, "stretched_runs": 0, "replans": 0, "via_paths": 0, "spline_runs": 0, "dense_failures": []}

    # -- constraints ------------------------------------------------------------------------------------------------
    @property
    def checker(self) -> StateChecker:
        """The state checker the timed samples go through."""
        if self._checker is None:
            t = self.task
            self._checker = StateChecker(t.evaluator, t.world, t.stance.base_pose, t.constrained, Counter(),
                                         limits=t.limits)
        return self._checker

    def _rows(self, run: Run, path: BlendedPath, grid: np.ndarray) -> tuple[list[LinearRows], float]:
        """TOPP-RA's rows at the gridpoints (the ZMP, cart-table and multibody, and the torques) and the run's ZMP
        floor (:meth:`_zmp_floor`) they keep."""
        P0, P1, P2 = path(grid, 0), path(grid, 1), path(grid, 2)
        t = self.task
        terms = com_path_terms(t.evaluator, P0, P1, P2, run.hold)
        polygon = t.evaluator.polygon
        static_margin = polygon.margin(terms.com[:, :2])
        floor_m = self._zmp_floor(static_margin)
        need = self._zmp_need(static_margin, floor_m + self.s.zmp_inner_m)
        z = zmp_rows(terms.com, terms.d1, terms.d2, polygon.normals, polygon.offsets, 0.0)
        room = z.room - need[:, None]
        rows = [LinearRows(grid, z.a, z.b, np.zeros_like(z.a), np.full_like(room, -np.inf), np.maximum(room, 0.0))]
        if self.s.zmp_angular_momentum:
            rows.append(self._multibody_zmp(run, P0, P1, P2, grid, polygon, need, room))
        if self.limits is not None:
            tau_s = self._static(run, P0)
            A, B = self._inertial(run).coefficients(P0, P1, P2)
            lim = self.limits.table.limit * self.s.effort_scale
            moved = (np.abs(A) + np.abs(B)).max(axis=0) > 1e-9  # the joints this motion loads at all
            if moved.any():
                A, B, tau_s, lim = A[:, moved], B[:, moved], tau_s[:, moved], lim[moved]
                rows.append(LinearRows(grid, A, B, tau_s, np.minimum(-lim, tau_s), np.maximum(lim, tau_s)))
        return rows, floor_m

    def _zmp_floor(self, static_margin: np.ndarray) -> float:
        """How far inside the polygon a run keeps its ZMP, given the static CoM margins along its path: the ZMP
        margin, or ``zmp_reserve_share`` of the smallest of those margins where that is more. A fast swing's ZMP
        steps set the body swaying, and the feet then feel more than the planned ZMP; keeping the ZMP close to
        where the CoM is at its tightest leaves that sway the rest of the margin. With ``zmp_reserve_cap_share`` and
        the plan's smallest static margin known (:meth:`time_plan`), the reserve asks at most that share of it plus
        ``zmp_overshoot_m``."""
        tightest = float(np.maximum(static_margin, 0.0).min()) if static_margin.size else 0.0
        reserve = self.s.zmp_reserve_share * tightest
        if self._asked is not None:
            self._asked.append(reserve)
        return max(self.zmp_margin_m, min(reserve, self._reserve_cap()))

    def _reserve_cap(self) -> float:
        """The most the ZMP reserve may ask (:meth:`_zmp_floor`): infinite until the plan's smallest static margin
        is known, or without ``zmp_reserve_cap_share``."""
        if self.plan_static_min_m is None or self.s.zmp_reserve_cap_share is None:
            return math.inf
        return self.s.zmp_reserve_cap_share * self.plan_static_min_m + self.s.zmp_overshoot_m

    def _once(self, key: tuple, compute):
        """``compute()`` the first time ``key`` is asked for within one :meth:`time_plan`; after that its result
        again, with what it added to the stats added again (the stats are those of computing it each time), as long
        as every ZMP reserve it asked (:meth:`_zmp_floor`) comes out the same under today's cap: the reserve cap's
        second timing recomputes only the runs the cap changes, and what no cap changes (the checks of a run's
        geometry, of a fallback's samples) runs once. A key names a run by id: the runs live as long as
        the :meth:`time_plan` that clears these."""
        cap = self._reserve_cap()
        kept = self._kept.get(key)
        if kept is not None and all(min(a, cap) == min(a, kept_cap) for a, kept_cap in kept[2]):
            result, grown, asked = kept
            _add_stats(self.stats, grown)
        else:
            outer, self._asked = self._asked, []
            before = _copied(self.stats)
            try:
                result = compute()
            finally:
                asked, self._asked = [(a, cap) for a in self._asked], outer
            self._kept[key] = (result, _grown(self.stats, before), asked)
        if self._asked is not None:
            self._asked.extend(a for a, _ in asked)
        return result

    @staticmethod
    def _zmp_need(static_margin: np.ndarray, floor_m: float) -> np.ndarray:
        """How far inside every edge the ZMP must stay at points whose CoM is ``static_margin`` inside: the run's
        floor; where the CoM is closer than that, as far inside as the CoM."""
        return np.minimum(floor_m, np.maximum(static_margin, 0.0))

    def _multibody_zmp(self, run: Run, P0, P1, P2, grid, polygon, need, room) -> LinearRows:
        """The ZMP of the whole body, the rate of its angular momentum included, at least ``need`` inside every
        edge: with ``P_dot, L_dot`` (world, about the origin) from :meth:`InertialTorques.momentum_rate`, the ZMP is
        ``(M g c_xy + (-L_dot_y, L_dot_x)) / (M g + P_dot_z)``, so ``n.zmp >= offset + need`` is the row
        ``n_x L_dot_y - n_y L_dot_x + (offset + need) P_dot_z <= M g (n.c - offset - need)``. At rest it is the
        CoM's; a fast arm swing moves it where the cart-table model does not see it."""
        inert = self._inertial(run)
        A, B = inert.momentum_rate(P0, P1, P2)
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
        key = None if run.hold is None else (run.hold.tcp_side, run.hold.T_tcp_obj.tobytes())
        if key not in self._inertials:
            if run.hold is None:
                self._inertials[key] = InertialTorques(t.robot, t.stance.base_pose)
            else:
                tcp = t.robot.spec.arms[run.hold.tcp_side].tcp
                self._inertials[key] = InertialTorques(t.robot, t.stance.base_pose, t.obj.mass_kg, tcp,
                                                       run.hold.T_tcp_obj, t.obj.com_local)
        return self._inertials[key]

    # -- checks of the samples ------------------------------------------------------------------------------------
    def _stretch_needed(self, run: Run, Q: np.ndarray, need_at: np.ndarray) -> float:
        """The time stretch (>= 1) the samples need to keep the limits as the checker sees them; 1 when they do."""
        dt = self.dt
        k = 1.0
        if len(Q) >= 2:
            v = np.abs(np.diff(Q, axis=0)) / dt
            k = max(k, float((v / self.vlim).max()))
        if len(Q) >= 3:
            a = np.abs(Q[2:] - 2.0 * Q[1:-1] + Q[:-2]) / (dt * dt)
            k = max(k, math.sqrt(float((a / self.alim).max())))
        t = self.task
        com = t.evaluator.evaluate(Q, run.hold, threshold_m=0.0).com
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

    # -- validation ---------------------------------------------------------------------------------------------------
    def _invalid_s(self, run: Run, path: "_Joined", starts: list[int], s: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """Path positions of the samples that fail the checks: every sample off the search's own segments (on a
        blend or a shortcut of the timing) through the state checker (collision, the margin, the static limits)
        with the grasping rules of the piece it belongs to; every sample and every midpoint between samples
        against the margin."""
        t = self.task
        bounds = [path.waypoint_s[i] for i in starts[1:]]
        piece_of = np.searchsorted(np.asarray(bounds), s, side="right") if bounds else np.zeros(len(s), int)
        new = off_path(Q, run.validated) if self.s.trust_search_segments else np.ones(len(Q), dtype=bool)
        self.stats["checked_samples"] += int(new.sum())
        bad = np.zeros(len(Q), dtype=bool)
        margin = t.evaluator.evaluate(Q, run.hold, threshold_m=0.0).margin
        bad |= margin < self.threshold - MARGIN_TOLERANCE_M
        for k, piece in enumerate(run.pieces):
            idx = np.flatnonzero((piece_of == k) & new)
            if not idx.size:
                continue
            ok, _ = self.checker.validity(run.hold, run.free_object, grasping_of(piece, run.hold), active=None)(Q[idx])
            bad[idx] |= ~ok
        bad_s = [s[bad]]
        if len(Q) >= 2:
            mids = 0.5 * (Q[1:] + Q[:-1])
            low = t.evaluator.evaluate(mids, run.hold, threshold_m=0.0).margin < self.threshold - MARGIN_TOLERANCE_M
            bad_s.append(0.5 * (s[1:] + s[:-1])[low])
        return np.concatenate(bad_s)

    def _fallback_failures(self, run: Run) -> str:
        """The search's own rest-to-rest samples of a run, every one through the state checker with its piece's
        grasping rule and grasp as the search validated it (``piece.hold``): empty when all pass, else what failed.
        Recorded in ``stats.timing.dense_failures``; the object at rest is checked where the plan tracks it, which
        can differ from the search's placement by an IK residual (a palm that touches the object at the grasp then
        counts), so it is reported, not refused."""
        if not self.s.trust_search_segments:
            failed = []
            for piece in run.pieces:
                Q = np.asarray(piece.waypoints, dtype=float)
                hold = piece.hold if run.hold is not None else None
                ok, _ = self.checker.validity(hold, run.free_object if hold is None else None, grasping_of(piece, hold),
                                              active=None)(Q)
                self.stats["checked_samples"] += len(Q)
                if not ok.all():
                    failed.append(f"{int((~ok).sum())} samples of the {piece.kind} ({piece.hand})")
            return "; ".join(failed)
        return ""

    def _refuse(self, why: str) -> None:
        self.stats["refused"].append(why)
        return None

    # -- one run ------------------------------------------------------------------------------------------------------
    def time_run(self, run: Run) -> tuple[list[np.ndarray], float, float] | None:
        """Per piece its samples (consecutive pieces share the boundary sample), the run's duration at full speed
        and its duration as timed (whole periods, rest copies left out); None when it cannot be timed here. The
        run is blended through its waypoints or, where ``spline_runs`` and it has a corner, goes along a spline of
        its waypoints (:class:`planner.motion.topp.SplinePath`): both paths are checked first, the one quicker on
        TOPP-RA's coarse ranking grid is timed and its samples checked, and the other only where that fails."""
        W, starts = waypoints_of(run)
        if len(W) < 2:
            return None
        refused = len(self.stats["refused"])
        blends = np.full(len(W) - 2, self.s.blend_rad)
        if self.s.path_check_rad > 0.0:
            blends = self._once(("blends", id(run)), lambda: self._checked_blends(run, W, starts, blends))
        spline = (self._once(("spline", id(run)), lambda: self._checked_spline(run, W, starts))
                  if self.s.spline_runs and len(W) > 2 else None)
        tries = []
        if blends is not None:
            tries.append((lambda: self._coarse_time(run, W, blends), 0, lambda: self._blended_run(run, W, starts, blends)))
        if spline is not None:
            P, at, path = spline
            tries.append((lambda: self._coarse_time(run, P, None, path), 1,
                          lambda: self._spline_run(run, P, at, starts, path)))
        if len(tries) == 2:  # the quicker on the coarse grid first
            tries.sort(key=lambda t: (t[0](), t[1]))
        for _, kind, timed_by in tries:
            timed = timed_by()
            if timed is not None:
                self.stats["spline_runs"] += kind
                del self.stats["refused"][refused:]  # what failed on the way to a run that is timed refused nothing
                return timed
        return None

    def _coarse_time(self, run: Run, W: np.ndarray, blends: np.ndarray | None, spline: SplinePath | None = None) -> float:
        """The run's TOPP-RA time on the ranking's coarse grid (``rank_grid_step_rad``), blended through W with
        ``blends`` (stopping where a blend is 0) or along ``spline``, without the checks of samples: what orders a
        run's two paths before either is timed in full."""
        stretches = [(W, None, spline)] if spline is not None else [
            (W[a:b + 1], blends[a:b - 1] if b - a >= 2 else np.zeros(0), None) for a, b in _cuts(blends)]
        total = 0.0
        for Wk, bk, sk in stretches:
            _, grid, sd, _ = self._profile(run, Wk, bk, self.s.rank_grid_step_rad, soft_ends=False, spline=sk)
            if sd is None:
                return math.inf
            total += float(profile_times(grid, sd)[-1])
        return total

    def _blended_run(self, run: Run, W: np.ndarray, starts: list[int],
                     blends: np.ndarray) -> tuple[list[np.ndarray], float, float] | None:
        """The run blended through its waypoints (``blends``, as its path's checks left them), blends shrunk
        further until every sample passes."""
        blends = blends.copy()
        for round_ in range(self.s.blend_rounds + 2):
            parts = []
            for a, b in _cuts(blends):
                part = self.time_part(run, W[a:b + 1], blends[a:b - 1] if b - a >= 2 else np.zeros(0))
                if part is None:
                    return None
                parts.append(part)
            # join the parts: each ends at rest at the waypoint where the next one starts
            s_all, Q_all = [], []
            offset = 0.0
            for k, part in enumerate(parts):
                s_k, Q_k = (part.s, part.Q) if k == 0 else (part.s[1:], part.Q[1:])
                s_all.append(s_k + offset)
                Q_all.append(Q_k)
                offset += part.path.length
            s_cat, Q_cat = np.concatenate(s_all), np.vstack(Q_all)
            whole = _Joined([part.path for part in parts])
            bad_s = self._invalid_s(run, whole, starts, s_cat, Q_cat)
            if not bad_s.size:
                break
            if not self._shrink_blends(run, whole, starts, blends, bad_s, round_):
                return None
        else:
            return None
        out = self._per_piece(run, starts, whole.waypoint_s, s_cat, Q_cat)
        if out is None:
            return None
        self.stats["blends"] += int(np.count_nonzero(blends > 0.0))
        return out, sum(part.full_speed_s for part in parts), (len(Q_cat) - 1) * self.dt

    def _checked_spline(self, run: Run, W: np.ndarray, starts: list[int]
                        ) -> tuple[np.ndarray, np.ndarray, SplinePath] | None:
        """A spline of the run's waypoints whose states every ``path_check_rad`` pass the checks of the timed
        samples: its control points, where each waypoint is among them, and the spline; None where none passes.
        Where the spline's states fail (it strays from the waypoints into an obstacle), both legs at the nearest
        waypoint get their midpoint as another control point, which pulls the spline towards that corner, and it is
        checked again, ``spline_rounds`` times at most."""
        P, at = W.copy(), np.arange(len(W))  # control points; where each waypoint is among them
        for _ in range(self.s.spline_rounds + 1):
            spline = SplinePath(P)
            if self.s.path_check_rad <= 0.0:
                return P, at, spline
            s = _spaced(spline.length, self.s.path_check_rad)
            Q = spline(s)
            Q[0], Q[-1] = W[0], W[-1]
            bad_s = self._invalid_s(run, spline, [int(at[i]) for i in starts], s, Q)
            if not bad_s.size:
                return P, at, spline
            corners = {int(np.argmin(np.abs(spline.waypoint_s - b))) for b in bad_s}
            legs = sorted({j for c in corners for j in (c - 1, c) if 0 <= j < len(P) - 1})
            P = np.insert(P, [j + 1 for j in legs], 0.5 * (P[legs] + P[[j + 1 for j in legs]]), axis=0)
            at = at + np.searchsorted(np.asarray(legs), at, side="left")
        return None

    def _spline_run(self, run: Run, P: np.ndarray, at: np.ndarray, starts: list[int],
                    spline: SplinePath) -> tuple[list[np.ndarray], float, float] | None:
        """The run along a checked spline (:meth:`_checked_spline`), without a stop: timed, then every sample
        checked, as a blended run's are; None (nothing refused: the blended run stands) where that fails."""
        piece_starts = [int(at[i]) for i in starts]
        refused = len(self.stats["refused"])
        part = self.time_part(run, P, np.zeros(0), spline=spline)
        del self.stats["refused"][refused:]  # the blended run's verdicts are the ones that count
        if part is None or self._invalid_s(run, spline, piece_starts, part.s, part.Q).size:
            return None
        out = self._per_piece(run, piece_starts, spline.waypoint_s, part.s, part.Q)
        return None if out is None else (out, part.full_speed_s, (len(part.Q) - 1) * self.dt)

    def _per_piece(self, run: Run, starts: list[int], waypoint_s: np.ndarray, s_cat: np.ndarray,
                   Q_cat: np.ndarray) -> list[np.ndarray] | None:
        """The run's samples split into its pieces, each from the sample nearest the path position of its first
        waypoint, with the rest copies at the run's ends; None when two pieces would share all their samples."""
        idx = [0]
        for i in starts[1:]:
            j = int(np.argmin(np.abs(s_cat - waypoint_s[i])))
            idx.append(min(max(j, idx[-1] + 1), len(Q_cat) - 2))
        idx.append(len(Q_cat) - 1)
        if any(b <= a for a, b in zip(idx[:-1], idx[1:])):
            return None
        rest = self.s.rest_samples
        out = []
        for k in range(len(run.pieces)):
            Qk = Q_cat[idx[k]: idx[k + 1] + 1]
            if k == 0 and rest:
                Qk = np.vstack([np.repeat(Qk[:1], rest, axis=0), Qk])
            if k == len(run.pieces) - 1 and rest:
                Qk = np.vstack([Qk, np.repeat(Qk[-1:], rest, axis=0)])
            out.append(Qk)
        return out

    def _shrink_blends(self, run: Run, whole: "_Joined", starts: list[int], blends: np.ndarray, bad_s: np.ndarray,
                       round_: int, count: bool = True) -> bool:
        """Halve (at the last round remove) in place every blend with a failing path position ``bad_s``; False (and
        the run refused) when a failure lies away from the blends, where halving them would not help. ``count``:
        the removals and the refusal go to the stats (not for a ranking's trial)."""
        hit = False
        for i in range(len(blends)):
            d = whole.blend_of(i + 1)
            if blends[i] <= 0.0 or d <= 0.0:
                continue
            if np.any(np.abs(bad_s - whole.waypoint_s[i + 1]) <= d + 1e-9):
                hit = True
                blends[i] = 0.0 if round_ >= self.s.blend_rounds else 0.5 * d
                self.stats["blends_removed"] += int(blends[i] == 0.0 and count)
        if not hit and count:  # a failure away from the blends: keep the validated rest-to-rest timing
            kinds = sorted({run.pieces[int(k)].kind for k in np.searchsorted(
                np.asarray([whole.waypoint_s[i] for i in starts[1:]]), bad_s, side="right")})
            self._refuse(f"{bad_s.size} samples of the {'/'.join(kinds)} off the blends fail the checks")
        return hit

    def _checked_blends(self, run: Run, W: np.ndarray, starts: list[int], blends: np.ndarray,
                        count: bool = True) -> np.ndarray | None:
        """The run's blends after the checks of its geometry, before any timing: states every ``path_check_rad`` of
        arc length along the blended path go through the same checks as the timed samples, and the blends are
        shrunk as the timed samples would have them shrunk. The timing (TOPP-RA, the sample checks) then runs once
        on a path that passes, where a failure found only after timing costs it again per round; an alternative
        that fails off its blends is refused before it is timed at all. None: refused."""
        blends = blends.copy()
        step = self.s.path_check_rad
        for round_ in range(self.s.blend_rounds + 2):
            cuts = _cuts(blends)
            paths = [BlendedPath(W[a:b + 1], blends[a:b - 1] if b - a >= 2 else np.zeros(0), self.s.blend_fill)
                     for a, b in cuts]
            whole = _Joined(paths)
            s_all, Q_all, offset = [], [], 0.0
            for k, (path, (a, b)) in enumerate(zip(paths, cuts)):
                s_k = _spaced(path.length, step)[(1 if k else 0):]
                Q_k = path(s_k)
                if k == 0:
                    Q_k[0] = W[a]
                Q_k[-1] = W[b]  # exactly the rest states, as the timed samples have them
                s_all.append(s_k + offset)
                Q_all.append(Q_k)
                offset += path.length
            bad_s = self._invalid_s(run, whole, starts, np.concatenate(s_all), np.vstack(Q_all))
            if not bad_s.size:
                return blends
            if not self._shrink_blends(run, whole, starts, blends, bad_s, round_, count):
                return None
        return None

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

    def time_part(self, run: Run, W: np.ndarray, blends: np.ndarray, spline: SplinePath | None = None) -> "Part | None":
        """One stretch between stops (blended through W, or along ``spline``), timed and checked; None when TOPP-RA
        finds no profile or the checks cannot be met by stretching."""
        path, grid, sd, floor_m = self._profile(run, W, blends, self.s.grid_step_rad, soft_ends=True, spline=spline)
        if sd is None:
            return self._refuse("TOPP-RA found no profile")
        stretch = 1.0
        for _ in range(self.s.check_rounds):
            s, T, _ = sample(path, grid, sd, self.dt, stretch / self.speed_scale)
            s = shaped(s, int(round(self.s.shaping_window_s / self.dt)))
            Q = path(s)
            Q[0], Q[-1] = W[0], W[-1]  # exactly the rest states (the polynomials reach them to rounding)
            com = self.task.evaluator.evaluate(Q, run.hold, threshold_m=0.0).com
            need_at = self._zmp_need(self.task.evaluator.polygon.margin(com[:, :2]), floor_m)
            k = self._stretch_needed(run, Q, need_at)
            if k <= 1.0 + 1e-9:
                self.stats["stretched_runs"] += int(stretch > 1.0)
                full = (max(1, int(math.ceil(T * stretch / self.dt - 1e-9))) + len(s) - 1
                        - max(1, int(math.ceil(T * stretch / self.speed_scale / self.dt - 1e-9)))) * self.dt
                return Part(path, s, Q, full)
            stretch *= max(k, 1.01)
        return self._refuse(f"the samples still exceed a limit after {self.s.check_rounds} stretches")

    def alternatives(self, pieces: list[MotionPiece]) -> list[list[MotionPiece]]:
        """The plan's pieces with their planned motions (more than one straight segment) made quicker, best first:
        level k holds each motion's k-th quickest path (its last one where it has fewer). Each motion's paths are its
        own, ``replans`` more T-RRT runs between its ends (:meth:`_replans`) and paths through task-space vias
        (:meth:`_via_paths`); the ``shortened_paths`` quickest
        of them at the velocity limits are all shortened alike (:meth:`_shortened`) before any is chosen, so that
        the path the ranking picks has had the same shortening as the ones it beats (the slower rest, which seldom
        win, are left as their replans made them: the shortening is a large share of the timing's cost). Every new
        segment is checked by the task's state checker, a replan's at the search's resolution and the full
        shortening's every ``shortcut_check_rad``. The ``alternatives`` quickest at the velocity limits are kept; with
        ``rank_by_timing`` they are then ranked by their TOPP-RA time on a coarse grid (:meth:`_estimated_time`),
        the corners and the balance included. The motions are worked on in this process and a forked helper at
        once (:meth:`_each_planned`)."""
        per_piece = self._quicker(pieces)
        levels = max(len(a) for a in per_piece) if per_piece else 0
        return [[a[min(k, len(a) - 1)] for a in per_piece] for k in range(levels)]

    def _quicker(self, pieces: list[MotionPiece],
                 ready: Callable[[dict[int, list[np.ndarray]]], bool] | None = None) -> list[list[MotionPiece]]:
        """Per non-empty piece of the plan (:func:`object_states`' order) its paths, quickest first
        (:meth:`alternatives`); the piece alone where it is not a planned motion. ``ready(found)``, with the paths
        found so far by piece, may do one piece of work they allow while this process waits for the helper's
        last ones, and says whether it did (:meth:`_each_planned`)."""
        t = self.task
        states = list(object_states(pieces, t.evaluator, t.placements[t.start_id]))
        planned = [k for k, (piece, *_) in enumerate(states) if _planned(piece)]
        # the transits first (T-RRT round the table, the longest to make quicker), so that neither process is left
        # with one of them at the end while the other waits; each piece's paths are its own whatever the order
        planned.sort(key=lambda k: (states[k][0].kind != "transit", k))
        found = self._each_planned(planned, lambda k: self._piece_paths(k, *states[k]), ready)
        return [[replace(piece, path=Q) for Q in found[k]] if k in found else [piece]
                for k, (piece, *_) in enumerate(states)]

    def _piece_paths(self, k: int, piece: MotionPiece, holding: str, hold: HoldSpec | None,
                     current: np.ndarray) -> list[np.ndarray]:
        """The paths of the plan's k-th piece (a planned motion), quickest first: see :meth:`alternatives`. Draws
        from the piece's own stream of the scenario's seed, so the result does not depend on which process runs it
        nor on the other pieces."""
        t = self.task
        weights = 1.0 / self.vlim
        validity = self.checker.validity(hold, None if hold is not None else current, None, active=None)
        rng = np.random.default_rng([t.scenario.seed, SHORTCUT_STREAM, k])
        P = np.asarray(piece.path, dtype=float)
        paths = self._quickest(self._replans(P, validity, rng, weights) + self._via_paths(piece, validity, rng, weights),
                               weights)
        full = min(len(paths), self.s.shortened_paths)
        settings = self._smoothing(self.s.shortcut_iterations)
        paths = self._quickest([self._shortened(Q, validity, rng, settings, weights) for Q in paths[:full]]
                               + paths[full:], weights)
        self.stats["shortened_s"] += path_length(P, weights) - path_length(paths[0], weights)
        if self.s.rank_by_timing and len(paths) > 1:  # the shortened quickest among the others, by their timing
            alone = Run([piece], holding, hold, None if hold is not None else current)
            took = [self._estimated_time(Q, alone) for Q in paths]
            paths = [paths[i] for i in sorted(range(len(paths)), key=lambda i: (took[i], i))]
        return paths

    def _each_planned(self, planned: list[int], paths_of, ready=None) -> dict[int, list[np.ndarray]]:
        """``paths_of(k)`` for each planned piece k, in this process and one forked helper at once where the task's
        ``parallel_motions`` allows it, forking is safe and a second core exists (the same paths either way: each
        piece draws from its own stream). The helper's check counts are added to this process's, and what each
        piece adds to the stats in the pieces' order (not in the order they ended). The pieces are shared in the order
        of ``planned``, each process taking the next one in turn; while this process waits for the helper's last
        ones, ``ready`` (see :meth:`_quicker`) is given the paths found so far."""
        checker = self.checker  # made here, before any fork, so both processes count into the same
        if not (self.task.settings.parallel_motions and len(planned) > 1 and spare_cores() > 0 and fork_is_safe()):
            return {k: paths_of(k) for k in sorted(planned)}

        def work(k: int, in_child: bool) -> tuple[list[np.ndarray], dict, Counter]:
            stats, counts = _copied(self.stats), Counter(checker.counters)
            paths = paths_of(k)
            grown, self.stats = _grown(self.stats, stats), stats  # added below in the pieces' order
            return paths, grown, (Counter(checker.counters) - counts) if in_child else Counter()

        idle = None if ready is None else (lambda done: ready({planned[i]: r[0] for i, r in done.items()}))
        results, error = share_with_child(planned, work, lambda: False, idle)
        found: dict[int, list[np.ndarray]] = {}
        for i, k in sorted(enumerate(planned), key=lambda ik: ik[1]):
            if i not in results:  # the helper failed before this one: it is planned here
                found[k] = paths_of(k)
                continue
            found[k], grown, counts = results[i]
            checker.counters.update(counts)
            _add_stats(self.stats, grown)
        if error is not None:
            self.stats.setdefault("helper_errors", []).append(error.strip().splitlines()[-1])
        return found

    def _shortened(self, Q: np.ndarray, validity, rng: np.random.Generator, settings: SmoothingSettings,
                   weights: np.ndarray) -> np.ndarray:
        """Path Q shortened in the time metric: ``shortcut_iterations`` random shortcuts, then
        ``partial_shortcut_iterations`` partial shortcuts (a whole-path shortcut cannot remove one joint's detour
        that the others need around an obstacle), both drawn from ``rng`` in this order, so a seed gives the same
        path. Q itself when both counts are 0."""
        if self.s.shortcut_iterations and len(Q) > 2:
            Q = shortcut(Q, validity, rng, settings, weights=weights).path
        if self.s.partial_shortcut_iterations and len(Q) > 2:
            Q = partial_shortcut(Q, validity, rng, self.s.partial_shortcut_iterations, settings.edge_resolution_rad,
                                 weights).path
        return Q

    def _smoothing(self, iterations: int) -> SmoothingSettings:
        """The search's shortcut settings with ``iterations`` draws, their new segments checked every
        ``shortcut_check_rad`` (never more coarsely than the search checks its own)."""
        base = self.task.settings.smoothing
        return base.model_copy(update={"iterations": iterations,
                                       "edge_resolution_rad": min(base.edge_resolution_rad, self.s.shortcut_check_rad)})

    def _quickest(self, paths: list[np.ndarray], weights: np.ndarray) -> list[np.ndarray]:
        """The ``alternatives`` paths quickest at the velocity limits, quickest first (ties in the given order)."""
        order = sorted(range(len(paths)), key=lambda i: (path_length(paths[i], weights), i))
        return [paths[i] for i in order[:self.s.alternatives]]

    def _estimated_time(self, P: np.ndarray, run: Run) -> float:
        """The time of path P, held as ``run`` holds, blended as a run is and timed by TOPP-RA with the same
        constraints (joint limits, torques, the ZMP), from rest to rest on a coarse grid and without the checks of
        the samples: what ranks a motion's alternatives. The time at the velocity limits leaves out the corners (a
        path of many short turns loses much more than one of a few long segments) and the balance (a held object
        swung where the ZMP binds). The blends are first checked as the run's timing checks them
        (:meth:`_checked_blends`, ``path_check_rad``): a path that hugs an obstacle keeps only small blends there,
        and its tight corners cost the time they will cost; a path whose geometry fails off its blends is never
        timed (infinite)."""
        keep = np.r_[True, np.abs(np.diff(P, axis=0)).max(axis=1) > SAME_WAYPOINT_RAD]
        W = P[keep]
        if len(W) < 2:
            return 0.0
        blends = np.full(len(W) - 2, self.s.blend_rad)
        if self.s.path_check_rad > 0.0 and len(W) > 2:
            blends = self._checked_blends(replace(run, pieces=[replace(run.pieces[0], path=W)]), W, [0], blends,
                                          count=False)
            if blends is None:
                return math.inf
        return self._coarse_time(run, W, blends)  # the robot stops where a blend had to go

    def _profile(self, run: Run, W: np.ndarray, blends: np.ndarray, grid_step_rad: float,
                 soft_ends: bool, spline: SplinePath | None = None
                 ) -> tuple[BlendedPath | SplinePath, np.ndarray, np.ndarray | None, float]:
        """The blended path through W (or ``spline``, when given), its TOPP-RA gridpoints ``grid_step_rad`` apart,
        the time-optimal path velocity at them under the joint, torque and ZMP limits (with the gentler starts and
        stops when ``soft_ends`` and the settings ask for them; None when TOPP-RA finds no profile), and the run's
        ZMP floor."""
        path = spline if spline is not None else BlendedPath(W, blends, self.s.blend_fill)
        grid = gridpoints_for(path, grid_step_rad, self.s.max_gridpoints)
        rows, floor_m = self._rows(run, path, grid)
        # TOPP-RA over the joints that move (the same arc length; the others add no constraint)
        cols = np.flatnonzero(np.ptp(W, axis=0) > 0)
        if soft_ends and self.s.end_acceleration_scale < 1.0 and self.s.end_zone_rad > 0.0:
            rows.append(self._soft_ends(path, grid, cols))
        if spline is not None:
            moving = spline.columns(cols)
        else:
            moving = BlendedPath(W[:, cols], blends, self.s.blend_fill)
            moving.breaks, moving.length = path.breaks, path.length  # the same parameter to the last bit
        sd = parameterize(moving, grid, self.vlim[cols] * self.s.velocity_scale,
                          self.alim[cols] * self.s.acceleration_scale, rows)
        return path, grid, sd, floor_m

    def _replans(self, P: np.ndarray, validity, rng: np.random.Generator, weights: np.ndarray) -> list[np.ndarray]:
        """P and ``replans`` more T-RRT runs between its ends (each shortened by ``replan_shortcut_iterations``
        shortcuts at the search's resolution), in the order they were planned; :meth:`alternatives` shortens the
        quickest of them alike and chooses. Only the joints P moves are planned; every run draws from ``rng`` and is
        capped by the T-RRT's rounds, so the paths are the seed's."""
        paths = [P]
        t = self.task
        active = np.flatnonzero(np.ptp(P, axis=0) > 0)
        trrt = t.settings.trrt.model_copy(update={"margin_cost": t.constrained})
        short = t.settings.smoothing.model_copy(update={"iterations": self.s.replan_shortcut_iterations})
        for _ in range(self.s.replans):
            res = plan_motion(P[0], P[-1], active, validity, t.robot.lower, t.robot.upper, rng, trrt,
                              Termination(trrt.max_iterations))
            self.stats["replans"] += 1
            if res.ok:
                paths.append(shortcut(res.path, validity, rng, short, weights=weights).path if len(res.path) > 2
                             else res.path)
        return paths

    def _via_paths(self, piece: MotionPiece, validity, rng: np.random.Generator,
                   weights: np.ndarray) -> list[np.ndarray]:
        """Paths between the ends of the piece's path through task-space via postures of its hand (none for a piece
        of both hands), checked every ``shortcut_check_rad`` as the full shortening checks its segments: the quick
        way around the table's edge that the replans' random samples seldom find
        (:mod:`planner.motion.task_space_vias`)."""
        if piece.hand not in ("left", "right"):
            return []
        P = np.asarray(piece.path, dtype=float)
        found = via_paths(P[0], P[-1], piece.hand, self.task.ik, validity, rng, weights, self.s.shortcut_check_rad,
                          self.s.vias)
        self.stats["via_paths"] += len(found)
        return found

    def time_plan(self, pieces: list[MotionPiece]) -> PlanTiming:
        """The plan's pieces made quicker, then timed run by run (a run whose samples fail the checks takes its
        next quicker alternative, at last the search's own path); and how much slower than full speed it is. The
        stats' ``quicker_paths_time_s`` is the wall time of making the paths quicker (:meth:`alternatives`: replans,
        shortcuts, ranking), less ``early_timing_s``, what this process spent meanwhile timing the runs whose paths
        were found while the helper worked on the last ones (:meth:`_time_early`: the first timing then finds them
        timed); the rest of the stage is the time parameterization and the checks of its samples.
        With ``zmp_reserve_cap_share`` set and a reserve to cap, the runs are timed twice: the first timing gives the
        plan's smallest static margin, which caps the ZMP reserve of the second (:meth:`_zmp_floor`)."""
        originals = runs_of(pieces, self.task)
        spans, first = [], 0
        for run in originals:  # run r holds the plan's non-empty pieces spans[r]
            spans.append(range(first, first + len(run.pieces)))
            first += len(run.pieces)
            run.validated = waypoints_of(run)[0]
        started = time.perf_counter()  # for stats only: nothing below depends on it
        try:
            per_piece = self._quicker(pieces, lambda found: self._time_early(originals, spans, found))
            levels = [[self._run_along(r, [per_piece[k][min(j, len(per_piece[k]) - 1)] for k in span], originals[r])
                       for r, span in enumerate(spans)]
                      for j in range(max((len(a) for a in per_piece), default=0))]
            self.stats["quicker_paths_time_s"] = time.perf_counter() - started - self.stats.get("early_timing_s", 0.0)
            if self.s.zmp_reserve_cap_share is not None and self.s.zmp_reserve_share > 0.0:  # no reserve: no cap
                before = _copied(self.stats)
                first, _ = self._time_runs(originals, levels)
                self.stats = before  # the first timing only measures the plan
                t = self.task
                self.plan_static_min_m = min(
                    float(t.evaluator.evaluate(np.asarray(p.waypoints, dtype=float), hold, threshold_m=0.0).margin.min())
                    for p, _, hold, _ in object_states(first, t.evaluator, t.placements[t.start_id]))
                self.stats["reserve_cap_m"] = self._reserve_cap()
            out, slack = self._time_runs(originals, levels)
        finally:
            # their keys name this plan's runs and paths by id
            self._kept, self._along, self._early, self._merged = {}, {}, set(), {}
        return PlanTiming(pieces=out, record={"method": METHOD, "speed_scale": self.speed_scale,
                                              "zmp_margin_m": self.zmp_margin_m,
                                              "zmp_reserve_share": self.s.zmp_reserve_share},
                          stats={**self.stats, "slack_s": slack})

    def _run_along(self, r: int, pieces: list[MotionPiece], original: Run) -> Run:
        """Run r of the plan along these pieces' paths: one object per run and paths within a :meth:`time_plan`,
        so that a run timed early (:meth:`_time_early`, kept by the run's id: :meth:`_once`) is found again. It holds
        what the original run holds: the paths differ, never their ends nor the waypoints the object's state is
        tracked through."""
        key = (r, tuple(id(p.path) for p in pieces))
        run = self._along.get(key)
        if run is None:
            run = self._along[key] = Run(pieces, original.holding, original.hold, original.free_object,
                                         original.validated)
        return run

    def _time_early(self, originals: list[Run], spans: list[range], found: dict[int, list[np.ndarray]]) -> bool:
        """While the helper works on the last motions (:meth:`_quicker`): time one run whose planned motions all
        have their paths, along the quickest of each, as the first timing will ask for it first (its result and
        stats kept for it by :meth:`_once`, the stats here left alone); whether there was one. The first timing's
        cap is the one of now (none yet), so what is kept is what it would compute."""
        for r, span in enumerate(spans):
            if r in self._early or any(_planned(p) and k not in found for k, p in zip(span, originals[r].pieces)):
                continue
            self._early.add(r)
            run = self._run_along(r, [replace(p, path=found[k][0]) if k in found else p
                                      for k, p in zip(span, originals[r].pieces)], originals[r])
            run = self._with_merged([run])[0]  # what the first timing tries first
            saved, self.stats = self.stats, _copied(self.stats)
            started = time.perf_counter()  # for stats only
            try:
                self._once(("run", id(run)), lambda: self.time_run(run))
            finally:
                self.stats = saved
                saved["early_timing_s"] = saved.get("early_timing_s", 0.0) + time.perf_counter() - started
            return True
        return False

    def _time_runs(self, originals: list[Run], levels: list[list[Run]]) -> tuple[list[MotionPiece], float]:
        """Each run timed: its quickest alternative whose samples pass, else the search's own path at last, each
        tried first with both arms at once where it has two arms' motions that can share it (``concurrent_arms``:
        :meth:`_with_merged`); the timed pieces and the time the whole-period rounding and the speed scale add.
        ``merged_runs`` counts the runs kept with both arms at once, ``merged_refused`` the merged tries whose
        samples failed, ``alternatives_dropped`` the one-arm-after-the-other ones."""
        out: list[MotionPiece] = []
        slack = 0.0
        for r, original in enumerate(originals):
            self.stats["runs"] += 1
            tries, seen = [], []
            for level in levels:
                run = level[r]
                key = [id(p.path) for p in run.pieces]
                if key not in seen:
                    seen.append(key)
                    tries.append(run)
            if [id(p.path) for p in original.pieces] not in seen:
                tries.append(original)
            for run in tries:
                run.validated = original.validated
            unmerged = len(tries)
            tries = self._with_merged(tries)
            merged = len(tries) - unmerged
            k, timed = self._first_timed(tries)
            self.stats["merged_refused"] += min(k, merged)
            self.stats["merged_runs"] += int(timed is not None and k < merged)
            if timed is None:
                run = original
                self.stats["fallback_runs"] += 1
                bad = self._once(("fallback", id(run)), lambda: self._fallback_failures(run))  # no cap changes it
                if bad:
                    self.stats["dense_failures"].append(bad)
                out.extend(run.pieces)
                continue
            self.stats["alternatives_dropped"] += max(k - merged, 0)
            Qs, full, actual = timed
            slack += actual - full
            out.extend(replace(p, waypoints=Q) for p, Q in zip(tries[k].pieces, Qs))
        return out, slack

    def _with_merged(self, tries: list[Run]) -> list[Run]:
        """A run's tries in the order they are timed: with ``concurrent_arms``, first each of them with both arms at
        once (:meth:`_both_arms`), then the tries themselves."""
        return (self._both_arms(tries) if self.s.concurrent_arms else []) + tries

    def _both_arms(self, runs: list[Run]) -> list[Run]:
        """Each of ``runs`` (in order) with its consecutive motions of the two arms made one (both arms at once:
        :func:`planner.regrasp.concurrent_arms.merged_pieces`), the second arm starting at each of ``LEADS`` in turn;
        none for a run without such motions. One object per run and lead within a :meth:`time_plan`, so that a run
        timed once (:meth:`_once`, by its id) is found again."""
        out = []
        for run in runs:
            for lead in LEADS:
                key = (id(run), lead)
                if key not in self._merged:
                    pieces = merged_pieces(run.pieces, 1.0 / self.vlim, lead)
                    self._merged[key] = None if pieces is None else Run(pieces, run.holding, run.hold,
                                                                        run.free_object, run.validated)
                if self._merged[key] is None:
                    break
                out.append(self._merged[key])
        return out

    def _first_timed(self, tries: list[Run]) -> tuple[int, tuple[list[np.ndarray], float, float] | None]:
        """The first of a run's alternatives that can be timed (:meth:`time_run`, once per plan where the reserve
        cap leaves its floors alone: :meth:`_once`): its index and timing; (the count, None) when none can."""
        for k, run in enumerate(tries):
            timed = self._once(("run", id(run)), lambda: self.time_run(run))
            if timed is not None:
                return k, timed
        return len(tries), None


def _planned(piece: MotionPiece) -> bool:
    """Whether a piece is a planned motion (more than one straight segment), which the timing makes quicker."""
    return piece.path is not None and len(piece.path) > 2


def _spaced(length: float, step: float) -> np.ndarray:
    """Path positions from 0 to ``length`` at most ``step`` apart, both ends included (the states a path's checks
    go through before it is timed)."""
    return np.linspace(0.0, length, max(2, int(math.ceil(length / step)) + 1))


def _copied(stats: dict) -> dict:
    """A copy of the timing's stats whose lists are copies too (the numbers are immutable)."""
    return {key: (list(v) if isinstance(v, list) else v) for key, v in stats.items()}


def _grown(after: dict, before: dict) -> dict:
    """What the timing's stats ``after`` added to ``before``: the numbers' differences, the lists' new entries."""
    return {key: (v[len(before.get(key, [])):] if isinstance(v, list) else v - before.get(key, 0))
            for key, v in after.items()}


def _add_stats(stats: dict, grown: dict) -> None:
    """Add what :func:`_grown` found to ``stats`` in place."""
    for key, v in grown.items():
        stats[key] = stats[key] + v if key in stats else v


def _cuts(blends: np.ndarray) -> list[tuple[int, int]]:
    """The (first, last) waypoint indices of the stretches between stops: the robot stops at the interior waypoints
    whose blend is 0."""
    stops = np.flatnonzero(blends <= 0.0) + 1
    cuts = [0, *stops.tolist(), len(blends) + 1]
    return list(zip(cuts[:-1], cuts[1:]))


@dataclass
class Part:
    """A stretch between stops, timed: its path, the path position and configuration of every sample."""

    path: BlendedPath
    s: np.ndarray
    Q: np.ndarray
    #: its duration at full speed, whole periods
    full_speed_s: float


class _Joined:
    """Several parts (each a BlendedPath from rest to rest) as one path position for bookkeeping."""

    def __init__(self, parts: list[BlendedPath]):
        self.parts = parts
        ws, blend = [0.0], [0.0]
        off = 0.0
        for p in parts:
            ws += (p.waypoint_s[1:] + off).tolist()
            blend += [*p.blend.tolist(), 0.0]
            off += p.length
        self.waypoint_s = np.array(ws)
        self._blend = np.array(blend)
        self.length = off

    def blend_of(self, i: int) -> float:
        return float(self._blend[i])
