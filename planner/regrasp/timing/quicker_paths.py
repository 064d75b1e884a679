"""Quicker paths for each planned motion of a solved plan: more T-RRT runs between its ends, paths through task-space
vias of the moving hand and, where none of those comes near the straight line's time, through joint-space box vias,
each shortened by random and partial shortcuts in the time metric, ranked by their TOPP-RA
time, the best one's corners eased; shared between this process and a forked helper, each motion drawing from its
own seeded stream so that the paths do not depend on which process made them."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from planner.forking import helper_may_fork
from planner.motion.corner_easing import eased
from planner.motion.smoothing import SmoothingSettings, partial_shortcut, path_length, shortcut
from planner.motion.task_space_vias import via_paths
from planner.motion.time_box_vias import box_via_paths
from planner.motion.trrt import plan_motion
from planner.regrasp.plan_assembly import MotionPiece, object_states
from planner.regrasp.timing.runs import Run, is_planned
from planner.regrasp.timing.stats import add_stats, stats_added, stats_copy
from planner.stability.evaluator import HoldSpec
from planner.termination import Termination

#: The random stream of the timing's shortcuts (apart from the search's hop streams).
SHORTCUT_STREAM = 7919
#: The random stream of the joint-space box vias (apart from the shortcuts', so adding them leaves those draws alone).
BOX_VIA_STREAM = 7927


class QuickerPaths:
    """The quicker paths of a plan's motions, a part of :class:`planner.regrasp.timing.plan_timer.PlanTimer`: it
    uses the timer's ``task``, ``s``, ``vlim``, ``stats``, ``checker``, its ranking by time (``_estimated_time``) and
    its sharing with a forked helper (``_with_helper``)."""

    def alternatives(self, pieces: list[MotionPiece]) -> list[list[MotionPiece]]:
        """The plan's pieces with their planned motions (more than one straight segment) made quicker, best first:
        level k holds each motion's k-th quickest path (its last one where it has fewer). Each motion's paths are its
        own, ``replans`` more T-RRT runs between its ends (:meth:`_replans`), paths through task-space vias
        (:meth:`_via_paths`) and, where none of those comes near the straight line's time, through joint-space box
        vias (:meth:`_box_via_paths`); the ``shortened_paths`` quickest
        of them at the velocity limits are all shortened alike (:meth:`_shortened`) before any is chosen, so that
        the path the ranking picks has had the same shortening as the ones it beats (the slower rest, which seldom
        win, are left as their replans made them: the shortening is a large share of the timing's cost). Every new
        segment is checked by the task's state checker, a replan's at the search's resolution and the full
        shortening's every ``shortcut_check_rad``. The ``alternatives`` quickest at the velocity limits are kept; with
        ``rank_by_timing`` they are then ranked by their TOPP-RA time on a coarse grid (:meth:`_estimated_time`),
        the corners and the balance included, and the best's corners eased (``corner_easing_sweeps``,
        :meth:`_with_eased`). The motions are worked on in this process and a forked helper at once
        (:meth:`_each_planned`)."""
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
        planned = [k for k, (piece, *_) in enumerate(states) if is_planned(piece)]
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
        found = self._replans(P, validity, rng, weights) + self._via_paths(piece, validity, rng, weights)
        paths = self._quickest(found + self._box_via_paths(k, P, found, validity, weights), weights)
        full = min(len(paths), self.s.shortened_paths)
        settings = self._smoothing(self.s.shortcut_iterations)
        paths = self._quickest([self._shortened(Q, validity, rng, settings, weights) for Q in paths[:full]]
                               + paths[full:], weights)
        self.stats["shortened_s"] += path_length(P, weights) - path_length(paths[0], weights)
        alone = Run([piece], holding, hold, None if hold is not None else current)
        took = None
        if self.s.rank_by_timing and len(paths) > 1:  # the shortened quickest among the others, by their timing
            took = [self._estimated_time(Q, alone) for Q in paths]
            order = sorted(range(len(paths)), key=lambda i: (took[i], i))
            paths, took = [paths[i] for i in order], [took[i] for i in order]
        if self.s.corner_easing_sweeps:
            paths = self._with_eased(paths, took, alone, validity)
        return paths

    def _with_eased(self, paths: list[np.ndarray], took: list[float] | None, alone: Run,
                    validity) -> list[np.ndarray]:
        """``paths`` with the first ``eased_paths`` of them eased (:func:`planner.motion.corner_easing.eased`), each
        eased path put just before the one it came from: each move judged by the path's TOPP-RA time on the
        ranking's coarse grid, blended as a run is (the piece alone, ``alone``, from rest to rest), its changed
        segments checked every ``shortcut_check_rad``; an eased path kept where its estimated time, its blends
        checked first (:meth:`_estimated_time`), is less than its source's (``took``: the ranking's times of
        ``paths``, which the eased ones then join in order of those times). Where the last pass's path is not (the
        estimate's blend checks can refuse a path the easing's segment checks passed), the latest earlier pass's
        path that is takes its place. The source stays, the next alternative should the eased one fail the checks
        of its samples."""
        out, times = [], []
        for i, Q in enumerate(paths):
            before = took[i] if took is not None else None
            if i < self.s.eased_paths and len(Q) > 2:
                res = eased(Q, validity,
                            lambda V: self._coarse_time(alone, V, np.full(len(V) - 2, self.s.blend_rad)),
                            self.s.shortcut_check_rad, self.s.corner_easing_sweeps)
                if res.moves:
                    before = self._estimated_time(Q, alone) if before is None else before
                    for path in reversed(res.passes):  # the last pass's path first (``res.path``)
                        after = self._estimated_time(path, alone)
                        if after < before:
                            break
                    if after < before:
                        self.stats["eased_s"] += before - after
                        self.stats["easing_moves"] += res.moves
                        out.append(path)
                        times.append(after)
            out.append(Q)
            times.append(before)
        if took is None:
            return out
        return [out[i] for i in sorted(range(len(out)), key=lambda i: (times[i], i))]

    def _each_planned(self, planned: list[int], paths_of, ready=None) -> dict[int, list[np.ndarray]]:
        """``paths_of(k)`` for each planned piece k, in this process and one forked helper at once where the task's
        ``parallel_motions`` allows it, forking is safe and a second core exists (the same paths either way: each
        piece draws from its own stream). The helper's check counts are added to this process's, and what each
        piece adds to the stats in the pieces' order (not in the order they ended). The pieces are shared in the order
        of ``planned``, each process taking the next one in turn; while this process waits for the helper's last
        ones, ``ready`` (see :meth:`_quicker`) is given the paths found so far."""
        if not (len(planned) > 1 and helper_may_fork(self.task.settings.parallel_motions)):
            return {k: paths_of(k) for k in sorted(planned)}

        def work(k: int, in_child: bool) -> tuple[list[np.ndarray], dict]:
            stats = stats_copy(self.stats)
            paths = paths_of(k)
            grown, self.stats = stats_added(self.stats, stats), stats  # added below in the pieces' order
            return paths, grown

        idle = None if ready is None else (lambda done: ready({planned[i]: r[0] for i, r in done.items()}))
        results = self._with_helper(planned, work, idle)
        found: dict[int, list[np.ndarray]] = {}
        for i, k in sorted(enumerate(planned), key=lambda ik: ik[1]):
            if i not in results:  # the helper failed before this one: it is planned here
                found[k] = paths_of(k)
                continue
            found[k], grown = results[i]
            add_stats(self.stats, grown)
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

    def _box_via_paths(self, k: int, P: np.ndarray, found: list[np.ndarray], validity,
                       weights: np.ndarray) -> list[np.ndarray]:
        """Paths between the ends of the k-th piece's path P through joint-space vias that keep it within a share of
        the straight line's time at the velocity limits (:mod:`planner.motion.time_box_vias`), checked every
        ``shortcut_check_rad``; none where a path ``found`` so far is within ``box_vias.min_ratio`` of that time. They
        draw from the piece's own stream of them, so the other paths' draws stay as they were."""
        s = self.s.box_vias
        line = path_length(P[[0, -1]], weights)
        if not s.draws or min(path_length(Q, weights) for Q in found) <= s.min_ratio * line:
            return []
        robot = self.task.robot
        out = box_via_paths(P[0], P[-1], validity, np.random.default_rng([self.task.scenario.seed, BOX_VIA_STREAM, k]),
                            weights, robot.lower, robot.upper, self.s.shortcut_check_rad, s)
        self.stats["box_via_paths"] += len(out)
        return out

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
