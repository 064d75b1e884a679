"""One run timed and checked: blended through its waypoints or along a spline of them, its geometry checked every
``path_check_rad`` before it is timed (a corner whose blend must shrink there pushed out where that passes), TOPP-RA
under the run's limits (:mod:`.limits`), then every timed sample and midpoint checked (collision with the grasping
rules of its piece, the margin, the static limits); blends with a failing sample are shrunk, at last removed. Also
the coarse TOPP-RA time that ranks a motion's paths."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from planner.motion.timing import MARGIN_TOLERANCE_M
from planner.motion.topp import BlendedPath, SplinePath, gridpoints_for, parameterize, profile_times, sample, shaped
from planner.regrasp.timing.runs import SAME_WAYPOINT_RAD, Run, grasping_of, off_path, waypoints_of


#: The choices of a corner pushed out (:meth:`RunTiming._pushed_corners`), in order: the share of its asked blend and
#: how far it is pushed, in units of the distance at which that blend passes through the corner.
PUSHES = ((1.0, 1.0), (1.0, 2.0), (0.5, 2.0), (0.25, 2.0))


class RunTiming:
    """One run's timing and checks, a part of :class:`planner.regrasp.timing.plan_timer.PlanTimer`: it uses the
    timer's ``task``, ``s``, ``dt``, ``speed_scale``, ``threshold``, ``vlim``, ``alim``, ``stats``, ``checker``, its
    limits (:class:`planner.regrasp.timing.limits.RunLimits`) and its results kept per plan (``_once``)."""

    def time_run(self, run: Run) -> tuple[list[np.ndarray], float, float] | None:
        """Per piece its samples (consecutive pieces share the boundary sample), the run's duration at full speed
        and its duration as timed (whole periods, rest copies left out); None when it cannot be timed here. The
        run is blended through its waypoints (the corners its checks shrank pushed out, :meth:`_pushed_corners`)
        or, where ``spline_runs`` and it has a corner, goes along a spline of
        its waypoints (:class:`planner.motion.topp.SplinePath`): both paths are checked first, the one quicker on
        TOPP-RA's coarse ranking grid is timed and its samples checked, and the other only where that fails."""
        W, starts = waypoints_of(run)
        if len(W) < 2:
            return None
        refused = len(self.stats["refused"])
        blends = np.full(len(W) - 2, self.s.blend_rad)
        blended_W = W  # the blended run's waypoints: the run's own, or with corners pushed out (_pushed_corners)
        if self.s.path_check_rad > 0.0:
            checked = self._once(("blends", id(run)), lambda: self._checked_blends(run, W, starts, blends))
            blended_W, blends = checked if checked is not None else (W, None)
        # where the blended path failed away from its corners, so does the polyline the spline's rounds pull it to
        rounds = self.s.spline_rounds if blends is not None else 0
        spline = (self._once(("spline", id(run)), lambda: self._checked_spline(run, W, starts, rounds))
                  if self.s.spline_runs and len(W) > 2 else None)
        tries = []
        if blends is not None:
            tries.append((lambda: self._coarse_time(run, blended_W, blends), 0,
                          lambda: self._blended_run(run, blended_W, starts, blends)))
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
        parts = [(W, None, spline)] if spline is not None else [(Wk, bk, None) for _, _, Wk, bk in stretches(W, blends)]
        total = 0.0
        for Wk, bk, sk in parts:
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
            for _, _, Wk, bk in stretches(W, blends):
                part = self.time_part(run, Wk, bk)
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
            whole = Joined([part.path for part in parts])
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

    def _checked_spline(self, run: Run, W: np.ndarray, starts: list[int], rounds: int
                        ) -> tuple[np.ndarray, np.ndarray, SplinePath] | None:
        """A spline of the run's waypoints whose states every ``path_check_rad`` pass the checks of the timed
        samples: its control points, where each waypoint is among them, and the spline; None where none passes.
        Where the spline's states fail (it strays from the waypoints into an obstacle), both legs at the nearest
        waypoint get their midpoint as another control point, which pulls the spline towards that corner, and it is
        checked again, ``rounds`` times at most. Each round brings the spline nearer the waypoints' polyline: where
        that fails away from its corners (the blended run was refused), the rounds cannot help, and
        :meth:`time_run` asks for none."""
        P, at = W.copy(), np.arange(len(W))  # control points; where each waypoint is among them
        for _ in range(rounds + 1):
            spline = SplinePath(P)
            if self.s.path_check_rad <= 0.0:
                return P, at, spline
            s = spaced(spline.length, self.s.path_check_rad)
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

    def _shrink_blends(self, run: Run, whole: "Joined", starts: list[int], blends: np.ndarray, bad_s: np.ndarray,
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
                        count: bool = True) -> tuple[np.ndarray, np.ndarray] | None:
        """The run's waypoints and blends after the checks of its geometry, before any timing: states every
        ``path_check_rad`` of arc length along the blended path go through the same checks as the timed samples, and
        the blends are shrunk as the timed samples would have them shrunk; with ``corner_push``, the corners whose
        blends were shrunk are then pushed out instead where that passes (:meth:`_pushed_corners`). The timing
        (TOPP-RA, the sample checks) then runs once on a path that passes, where a failure found only after timing
        costs it again per round; an alternative that fails off its blends is refused before it is timed at all.
        None: refused."""
        asked = blends
        blends = blends.copy()
        for round_ in range(self.s.blend_rounds + 2):
            whole, bad_s = self._path_failures(run, W, starts, blends)
            if not bad_s.size:
                break
            if not self._shrink_blends(run, whole, starts, blends, bad_s, round_, count):
                return None
        else:
            return None
        if self.s.corner_push:
            return self._pushed_corners(run, W, starts, asked, blends, count)
        return W, blends

    def _pushed_corners(self, run: Run, W: np.ndarray, starts: list[int], asked: np.ndarray, passed: np.ndarray,
                        count: bool) -> tuple[np.ndarray, np.ndarray]:
        """Each corner whose blend the checks shrank (``passed`` < ``asked``) moved outwards, away from where its
        blend cuts in: ``W_i - k (d / 4)(u_out - u_in)`` for a blend of half-length ``d`` between the unit directions
        ``u_in`` and ``u_out`` (of the path before the push). With ``k = 1`` the blend passes through the checked
        corner instead of inside it (nearly: the pushed legs are a little longer and turn a little more), where
        the obstacle that shrank it is; a tight corner near the table's edge then keeps a larger blend, and the robot
        does not slow to a near stop there. The pushed path is checked as the blended one is, and a failing state is
        put down to the nearest pushed corner whose legs hold it; that corner takes its next choice (:data:`PUSHES`:
        the asked blend pushed once, then twice as far, then smaller blends pushed twice as far), and at last its
        shrunk blend unpushed, until every state passes (at worst the path that passed). Returns the waypoints and
        blends."""
        shrunk = np.flatnonzero(passed < asked) + 1  # interior waypoints whose blend was shrunk or removed
        if not shrunk.size:
            return W, passed
        choices = {int(i): [(asked[i - 1] * size, k) for size, k in PUSHES if asked[i - 1] * size > passed[i - 1]]
                   for i in shrunk}
        at = {i: 0 for i in choices}
        unit = np.diff(W, axis=0)
        unit /= np.linalg.norm(unit, axis=1)[:, None]
        robot = self.task.robot
        while True:
            pushed = [i for i in choices if at[i] < len(choices[i])]
            if not pushed:
                return W, passed
            blends = passed.copy()
            for i in pushed:
                blends[i - 1] = choices[i][at[i]][0]
            d = Joined([BlendedPath(Wk, bk, self.s.blend_fill) for _, _, Wk, bk in stretches(W, blends)])
            pushed_W = W.copy()
            for i in pushed:
                k = choices[i][at[i]][1]
                pushed_W[i] = np.clip(W[i] - k * 0.25 * d.blend_of(i) * (unit[i] - unit[i - 1]),
                                      robot.lower, robot.upper)
            whole, bad_s = self._path_failures(run, pushed_W, starts, blends)
            if not bad_s.size:
                if count:  # a blend the checks removed and a push restored is not removed
                    self.stats["corners_pushed"] += len(pushed)
                    self.stats["blends_removed"] -= sum(int(passed[i - 1] == 0.0) for i in pushed)
                return pushed_W, blends
            ws = whole.waypoint_s
            failed = set()
            for at_s in bad_s:
                near = [i for i in pushed if ws[i - 1] <= at_s <= ws[i + 1]]
                if not near:  # a failure no pushed corner explains: the path that passed
                    return W, passed
                failed.add(min(near, key=lambda i: abs(at_s - ws[i])))
            for i in failed:
                at[i] += 1

    def _path_failures(self, run: Run, W: np.ndarray, starts: list[int], blends: np.ndarray
                       ) -> tuple["Joined", np.ndarray]:
        """The blended path through W (stopping where a blend is 0) as one path position, and the positions of its
        states every ``path_check_rad`` that fail the checks of the timed samples (:meth:`_invalid_s`)."""
        step = self.s.path_check_rad
        cuts = stretches(W, blends)
        paths = [BlendedPath(Wk, bk, self.s.blend_fill) for _, _, Wk, bk in cuts]
        whole = Joined(paths)
        s_all, Q_all, offset = [], [], 0.0
        for k, (path, (a, b, _, _)) in enumerate(zip(paths, cuts)):
            s_k = spaced(path.length, step)[(1 if k else 0):]
            Q_k = path(s_k)
            if k == 0:
                Q_k[0] = W[a]
            Q_k[-1] = W[b]  # exactly the rest states, as the timed samples have them
            s_all.append(s_k + offset)
            Q_all.append(Q_k)
            offset += path.length
        return whole, self._invalid_s(run, whole, starts, np.concatenate(s_all), np.vstack(Q_all))

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
            k = self._stretch_needed(run, Q, com, need_at)
            if k <= 1.0 + 1e-9:
                self.stats["stretched_runs"] += int(stretch > 1.0)
                full = (max(1, int(math.ceil(T * stretch / self.dt - 1e-9))) + len(s) - 1
                        - max(1, int(math.ceil(T * stretch / self.speed_scale / self.dt - 1e-9)))) * self.dt
                return Part(path, s, Q, full)
            stretch *= max(k, 1.01)
        return self._refuse(f"the samples still exceed a limit after {self.s.check_rounds} stretches")

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
            checked = self._checked_blends(replace(run, pieces=[replace(run.pieces[0], path=W)]), W, [0], blends,
                                           count=False)
            if checked is None:
                return math.inf
            W, blends = checked
        return self._coarse_time(run, W, blends)  # the robot stops where a blend had to go

    def _invalid_s(self, run: Run, path: "Joined", starts: list[int], s: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """Path positions of the samples that fail the checks: every sample off the search's own segments (on a
        blend or a shortcut of the timing) through the state checker (collision, the margin, the static limits)
        with the grasping rules of the piece it belongs to; every sample and every midpoint between samples
        against the margin (a sample the state checker sees is tested on the margin the checker computed; only the
        others' margins are computed here)."""
        t = self.task
        bounds = [path.waypoint_s[i] for i in starts[1:]]
        piece_of = np.searchsorted(np.asarray(bounds), s, side="right") if bounds else np.zeros(len(s), int)
        new = off_path(Q, run.validated) if self.s.trust_search_segments else np.ones(len(Q), dtype=bool)
        self.stats["checked_samples"] += int(new.sum())
        bad = np.zeros(len(Q), dtype=bool)
        if not new.all():
            seen = np.flatnonzero(~new)
            margin = t.evaluator.evaluate(Q[seen], run.hold, threshold_m=0.0).margin
            bad[seen] = margin < self.threshold - MARGIN_TOLERANCE_M
        for k, piece in enumerate(run.pieces):
            idx = np.flatnonzero((piece_of == k) & new)
            if not idx.size:
                continue
            ok, margin = self.checker.validity(run.hold, run.free_object, grasping_of(piece, run.hold),
                                               active=None)(Q[idx])
            bad[idx] |= ~ok | (margin < self.threshold - MARGIN_TOLERANCE_M)
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


def spaced(length: float, step: float) -> np.ndarray:
    """Path positions from 0 to ``length`` at most ``step`` apart, both ends included (the states a path's checks
    go through before it is timed)."""
    return np.linspace(0.0, length, max(2, int(math.ceil(length / step)) + 1))


def between_stops(blends: np.ndarray) -> list[tuple[int, int]]:
    """The (first, last) waypoint indices of the stretches between stops: the robot stops at the interior waypoints
    whose blend is 0."""
    stops = np.flatnonzero(blends <= 0.0) + 1
    cuts = [0, *stops.tolist(), len(blends) + 1]
    return list(zip(cuts[:-1], cuts[1:]))


def stretches(W: np.ndarray, blends: np.ndarray) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """Per stretch between stops (:func:`between_stops`): its first and last waypoint indices, its waypoints and the
    blends of its interior waypoints (what one rest-to-rest part of a blended run is made of)."""
    return [(a, b, W[a:b + 1], blends[a:b - 1] if b - a >= 2 else np.zeros(0)) for a, b in between_stops(blends)]


@dataclass
class Part:
    """A stretch between stops, timed: its path, the path position and configuration of every sample."""

    path: BlendedPath
    s: np.ndarray
    Q: np.ndarray
    #: its duration at full speed, whole periods
    full_speed_s: float


class Joined:
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
