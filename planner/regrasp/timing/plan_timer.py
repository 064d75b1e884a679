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
   ``zmp_reserve_share`` (``zmp_reserve_share_one_foot`` on one foot) of the run's smallest static CoM margin
   where that is more (where the CoM itself is closer to an edge than that, as far inside as the CoM). The CoM
   terms come from :mod:`planner.stability.com_path`, the torques from :mod:`planner.stability.effort` and
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

Each step has its module in this package: the runs (:mod:`.runs`), the quicker paths tried for each
planned motion (:mod:`.quicker_paths`), the limits TOPP-RA keeps and the samples are held to (:mod:`.limits`), one
run timed and checked (:mod:`.run_timing`), both arms at once around a handover (:mod:`.concurrent_arms`). This
module puts them together for a plan: :class:`PlanTimer`.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from planner.forking import helper_may_fork
from planner.regrasp.fork_share import share_with_child
from planner.regrasp.plan_assembly import MotionPiece, object_states
from planner.regrasp.state_checker import StateChecker
from planner.regrasp.timing.concurrent_arms import LEADS, merged_pieces
from planner.regrasp.timing.limits import RunLimits
from planner.regrasp.timing.quicker_paths import QuickerPaths
from planner.regrasp.timing.run_timing import RunTiming
from planner.regrasp.timing.runs import Run, is_planned, runs_of, waypoints_of
from planner.regrasp.timing.settings import PlanTimingSettings
from planner.regrasp.timing.stats import add_stats, stats_added, stats_copy
from planner.stability.effort import EffortEvaluator
from planner.termination import never

METHOD = "topp-ra"


@dataclass
class PlanTiming:
    """The retimed pieces and what the plan records of the timing."""

    pieces: list[MotionPiece]
    record: dict
    stats: dict = field(default_factory=dict)


class PlanTimer(RunLimits, RunTiming, QuickerPaths):
    """Times the runs of one plan for one task. It holds what one timing shares: the task, the settings, the stats,
    the state checker and the results kept within one :meth:`time_plan` (:meth:`_once`); its parts, the limits
    (:class:`RunLimits`), one run's timing (:class:`RunTiming`) and the quicker paths (:class:`QuickerPaths`), work on
    these."""

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
        #: the paths' terms at their gridpoints within one :meth:`time_plan`, by the path's points (:meth:`_geometry`)
        self._geometries: dict = {}
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
        #: the last line of each failed helper's error (its work then done here), kept apart from the stats, which a
        #: first timing's replay would drop: ``stats.timing.helper_errors`` when there is one
        self.helper_errors: list[str] = []
        self.stats = {"merged_runs": 0, "merged_refused": 0, "merged_slower": 0, "shortened_s": 0.0,
                      "alternatives_dropped": 0, "refused": [], "checked_samples": 0, "runs": 0, "blends": 0,
                      "blends_removed": 0, "corners_pushed": 0, "fallback_runs": 0, "stretched_runs": 0, "replans": 0,
                      "via_paths": 0, "box_via_paths": 0, "eased_s": 0.0, "easing_moves": 0, "spline_runs": 0,
                      "dense_failures": []}

    @property
    def reserve_share(self) -> float:
        """The ZMP reserve's share for this task's stance (:meth:`PlanTimingSettings.reserve_share`: more on one
        foot)."""
        return self.s.reserve_share(self._soles_in_contact)

    @property
    def local_share(self) -> float:
        """The share of the CoM's own margin the ZMP keeps at each point for this task's stance
        (:meth:`PlanTimingSettings.local_share`: on one foot only)."""
        return self.s.local_share(self._soles_in_contact)

    @property
    def _soles_in_contact(self) -> int:
        """How many of the stance's soles are on the ground (the shares differ on one foot)."""
        return sum(1 for foot in self.task.stance.feet if foot.in_contact)

    @property
    def checker(self) -> StateChecker:
        """The state checker the timed samples go through."""
        if self._checker is None:
            t = self.task
            self._checker = StateChecker(t.evaluator, t.world, t.stance.base_pose, t.constrained, Counter(),
                                         limits=t.limits)
        return self._checker

    def _once(self, key: tuple, compute):
        """``compute()`` the first time ``key`` is asked for within one :meth:`time_plan`; after that its result
        again, with what it added to the stats added again (the stats are those of computing it each time), as long
        as every ZMP reserve it asked (:meth:`_zmp_floor`) comes out the same under today's cap: the reserve cap's
        second timing recomputes only the runs the cap changes, and what no cap changes (the checks of a run's
        geometry, of a fallback's samples) runs once. A key names a run by id: the runs live as long as
        the :meth:`time_plan` that clears these."""
        kept = self._kept_now(key)
        if kept is not None:
            result, grown, asked = kept
            add_stats(self.stats, grown)
        else:
            cap = self._reserve_cap()
            outer, self._asked = self._asked, []
            before = stats_copy(self.stats)
            try:
                result = compute()
            finally:
                asked, self._asked = [(a, cap) for a in self._asked], outer
            self._kept[key] = (result, stats_added(self.stats, before), asked)
        if self._asked is not None:
            self._asked.extend(a for a, _ in asked)
        return result

    def _kept_now(self, key: tuple) -> tuple | None:
        """What :meth:`_once` keeps for ``key`` (result, stats added, reserves asked) where it still holds under
        today's reserve cap; None where it must be computed (again)."""
        cap = self._reserve_cap()
        kept = self._kept.get(key)
        return kept if kept is not None and all(min(a, cap) == min(a, kept_cap) for a, kept_cap in kept[2]) else None

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
            if self.s.zmp_reserve_cap_share is not None and self.reserve_share > 0.0:  # no reserve: no cap
                before = stats_copy(self.stats)
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
            self._kept, self._along, self._early, self._merged, self._geometries = {}, {}, set(), {}, {}
        return PlanTiming(pieces=out, record={"method": METHOD, "speed_scale": self.speed_scale,
                                              "zmp_margin_m": self.zmp_margin_m,
                                              "zmp_reserve_share": self.reserve_share,
                                              "zmp_local_share": self.local_share},
                          stats={**self.stats, **({"helper_errors": list(self.helper_errors)} if self.helper_errors
                                                   else {}), "slack_s": slack})

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
            if r in self._early or any(is_planned(p) and k not in found for k, p in zip(span, originals[r].pieces)):
                continue
            self._early.add(r)
            run = self._run_along(r, [replace(p, path=found[k][0]) if k in found else p
                                      for k, p in zip(span, originals[r].pieces)], originals[r])
            run = self._with_merged([run])[0]  # what the first timing tries first
            saved, self.stats = self.stats, stats_copy(self.stats)
            started = time.perf_counter()  # for stats only
            try:
                self._once(("run", id(run)), lambda: self.time_run(run))
            finally:
                self.stats = saved
                saved["early_timing_s"] = saved.get("early_timing_s", 0.0) + time.perf_counter() - started
            return True
        return False

    def _time_runs(self, originals: list[Run], levels: list[list[Run]]) -> tuple[list[MotionPiece], float]:
        """Each run timed: its quickest alternative whose samples pass, else the search's own path at last, tried
        with both arms at once too where it has two arms' motions that can share it (``concurrent_arms``:
        :meth:`_with_merged`, :meth:`_kept_try`); the timed pieces and the time the whole-period rounding and the
        speed scale add. ``merged_runs`` counts the runs kept with both arms at once, ``merged_refused`` the merged
        tries whose samples failed, ``merged_slower`` the runs whose first merged try that passed was slower than
        the arms one after the other, ``alternatives_dropped`` the one-arm-after-the-other tries whose samples
        failed before the one kept."""
        out: list[MotionPiece] = []
        slack = 0.0
        tries_of = [self._tries(r, original, levels) for r, original in enumerate(originals)]
        self._time_shared(tries_of)
        for original, (tries, merged) in zip(originals, tries_of):
            self.stats["runs"] += 1
            k, timed, refused = self._kept_try(tries, merged)
            self.stats["merged_refused"] += refused[0]
            if timed is None:
                run = original
                self.stats["fallback_runs"] += 1
                bad = self._once(("fallback", id(run)), lambda: self._fallback_failures(run))  # no cap changes it
                if bad:
                    self.stats["dense_failures"].append(bad)
                out.extend(run.pieces)
                continue
            self.stats["alternatives_dropped"] += refused[1]
            self.stats["merged_runs"] += int(k < merged)
            self.stats["merged_slower"] += int(k >= merged and refused[0] < merged)
            Qs, full, actual = timed
            slack += actual - full
            out.extend(replace(p, waypoints=Q) for p, Q in zip(tries[k].pieces, Qs))
        return out, slack

    def _kept_try(self, tries: list[Run], merged: int
                  ) -> tuple[int, tuple[list[np.ndarray], float, float] | None, tuple[int, int]]:
        """Which of a run's tries is kept (the first ``merged`` of them with both arms at once, :meth:`_tries`): the
        first merged one whose samples pass, unless it is a merge of another path than the first one-arm try's (the
        best-ranked path's merges all failed) and the first one-arm-after-the-other try that passes is quicker; else
        the first that passes. At the velocity limits a merge of a path takes no longer than the path's arms one
        after the other (the second arm starts sooner), but a merge of a slower path can take longer than the best
        path with the arms one after the other. Its index, its timing (None: none passed) and how many merged and
        one-arm tries were refused on the way (:meth:`_first_timed`)."""
        k, timed = self._first_timed(tries[:merged])
        if timed is None:
            u, timed = self._first_timed(tries[merged:])
            return merged + u, timed, (merged, u)
        if not self._merges_of(tries[merged], tries[k]):
            u, alone = self._first_timed(tries[merged:])
            if alone is not None and alone[2] < timed[2]:
                return merged + u, alone, (k, u)
        return k, timed, (k, 0)

    def _merges_of(self, run: Run, merged: Run) -> bool:
        """Whether ``merged`` is ``run`` with both arms at once (:meth:`_both_arms`), at any lead."""
        return any(self._merged.get((id(run), lead)) is merged for lead in LEADS)

    def _tries(self, r: int, original: Run, levels: list[list[Run]]) -> tuple[list[Run], int]:
        """Run r's alternatives in the order they are timed (each level's path once, the search's own path last, each
        first with both arms at once: :meth:`_with_merged`), and how many of them are merged ones."""
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
        return tries, len(tries) - unmerged

    def _time_shared(self, tries_of: list[tuple[list[Run], int]]) -> None:
        """Each run's timings (:meth:`_kept_try` of its tries and their merged count, :meth:`_tries`) worked out in
        this process and a forked helper at once (:meth:`_with_helper`), where the task's ``parallel_motions``
        allows it, forking is safe and a second core exists; kept (:meth:`_once`, the stats here left alone) for the
        pass of :meth:`_time_runs` that follows, which then finds them timed. The same results either way: a run's
        timing depends on the run and the reserve's cap alone, and what the helper computed is kept here as this
        process would have kept it. Where the helper fails, the pass times its runs itself."""
        todo = [(tries, merged) for tries, merged in tries_of if self._kept_now(("run", id(tries[0]))) is None]
        if not (len(todo) > 1 and helper_may_fork(self.task.settings.parallel_motions)):
            return

        def work(job: tuple[list[Run], int], in_child: bool) -> dict | None:
            before = dict(self._kept) if in_child else None  # the helper sends back what it kept anew
            saved, self.stats = self.stats, stats_copy(self.stats)
            try:
                self._kept_try(*job)
            finally:
                self.stats = saved
            return None if before is None else {key: v for key, v in self._kept.items() if before.get(key) is not v}

        # the longest runs first, so that neither process is left with one of them at the end
        todo.sort(key=lambda job: -sum(len(p.joint_path()) for p in job[0][0].pieces))
        for kept in self._with_helper(todo, work).values():
            if kept is not None:
                self._kept.update(kept)

    def _with_helper(self, jobs: list, work: Callable[[Any, bool], Any],
                     idle: Callable[[dict[int, Any]], bool] | None = None) -> dict[int, Any]:
        """``work(job, in_child)`` for each job, in this process and a forked helper at once
        (:func:`planner.regrasp.fork_share.share_with_child`; call where :func:`planner.forking.helper_may_fork`):
        the results by job index, a lost helper's unfinished ones missing, for the caller to work out here. The
        helper's check counts are added to this process's checker and its loss to ``helper_errors``; ``idle``, when
        given, gets the results so far while this process waits (see ``share_with_child``)."""
        checker = self.checker  # made here, before the fork, so both processes count into the same

        def counted(job: Any, in_child: bool) -> tuple[Any, Counter]:
            counts = Counter(checker.counters)
            result = work(job, in_child)
            return result, (Counter(checker.counters) - counts) if in_child else Counter()

        waiting = None if idle is None else (lambda done: idle({i: r for i, (r, _) in done.items()}))
        results, error = share_with_child(jobs, counted, never, waiting)
        for _, counts in results.values():
            checker.counters.update(counts)
        if error is not None:
            self.helper_errors.append(error.strip().splitlines()[-1])
        return {i: result for i, (result, _) in results.items()}

    def _with_merged(self, tries: list[Run]) -> list[Run]:
        """A run's tries in the order they are timed: with ``concurrent_arms``, first each of them with both arms at
        once (:meth:`_both_arms`), then the tries themselves."""
        return (self._both_arms(tries) if self.s.concurrent_arms else []) + tries

    def _both_arms(self, runs: list[Run]) -> list[Run]:
        """Each of ``runs`` (in order) with its consecutive motions of the two arms made one (both arms at once:
        :func:`planner.regrasp.timing.concurrent_arms.merged_pieces`), the second arm starting at each of ``LEADS`` in
        turn; none for a run without such motions. One object per run and lead within a :meth:`time_plan`, so that a run
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
