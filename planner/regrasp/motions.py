"""The regrasp planner's motion validator: the motion of one hop between two nodes, or why there is none.

Like OMPL's ``MotionValidator``, it answers whether a hop can be made, here with the motion
itself: simple via postures first (the straight line, the arm's ready posture, the hand lifted
above either end or above the joint-space middle; the quickest valid one at the velocity limits), else the energy-based T-RRT (:mod:`planner.motion.trrt`) and shortcuts, then
the time parametrisation within the velocity and acceleration limits with the ZMP inside the
polygon (:mod:`planner.motion.timing`). Every state on the way is checked by the task's
:class:`~planner.regrasp.state_checker.StateChecker`. Each hop draws from its own generator.
"""

from __future__ import annotations

import numpy as np

from planner.motion.smoothing import path_length, shortcut
from planner.motion.timing import time_path
from planner.motion.trrt import plan_motion
from planner.regrasp.failure_cause import FailureCause
from planner.regrasp.graph import HOP_KINDS, HandoverNode, PlacementNode, Validation
from planner.regrasp.plan_assembly import MotionPiece
from planner.regrasp.results import HandoverPoses, KeyPoses
from planner.regrasp.settings import Side
from planner.regrasp.search_data import SearchData
from planner.regrasp.task import Task
from planner.stability.evaluator import HoldSpec
from planner.termination import Termination


class MotionValidator:
    """Motions of one hand configuration's hops, from the key poses its node validation found.

    ``keyposes`` and ``handovers`` are the hand configuration's own (shared, not copied): the
    handover's transits are planned into its pieces once a path through it is otherwise valid.
    """

    def __init__(self, task: Task, data: SearchData, keyposes: dict[PlacementNode, KeyPoses],
                 handovers: dict[HandoverNode, HandoverPoses], termination: Termination):
        self.task = task
        self.data = data
        self.keyposes = keyposes
        self.handovers = handovers
        #: the plan's termination; each motion takes its deadline and cancel with the T-RRT's own iteration cap
        self.termination = termination

    def motion(self, qa: np.ndarray, qb: np.ndarray, active: np.ndarray, hold: HoldSpec | None,
                free_object: np.ndarray | None, grasping: str | None, rng: np.random.Generator) -> np.ndarray | None:
        """A valid joint path qa -> qb (T-RRT, then shortcuts), or None."""
        t, s = self.task, self.task.settings
        validity = self.data.checker.validity(hold, free_object, grasping, active=None)
        via = self._via_ready(qa, qb, active, validity, rng)
        if via is not None:
            return via
        trrt = s.trrt.model_copy(update={"margin_cost": t.constrained})
        termination = self.termination.with_iterations(trrt.max_iterations)
        for _ in range(s.motion_attempts):
            res = plan_motion(qa, qb, active, validity, t.robot.lower, t.robot.upper, rng, trrt, termination)
            if res.ok:
                break
        else:
            return None
        path = res.path
        if len(path) > 2:
            path = shortcut(path, validity, rng, s.smoothing, termination, weights=1.0 / t.robot.velocity_limit).path
        return path

    def _via_ready(self, qa: np.ndarray, qb: np.ndarray, active: np.ndarray, validity,
                   rng: np.random.Generator) -> np.ndarray | None:
        """A short valid path through simple via postures, or None (then T-RRT searches).

        Candidates: the straight line; through the moving arm's ready posture (hand raised in front
        of the shoulder); through the hand lifted above either end (IK from that end) or above the
        joint-space middle of the two. They are tried quickest first (the time the path takes at the
        velocity limits), so the first valid one is the quickest. Most moves between table poses
        are one of these.
        """
        t = self.task
        sides = [side for side in ("left", "right") if np.all(np.isin(t.arm_only[side], active))]
        candidates: list[list[np.ndarray]] = [[qa, qb]]
        for side in sides:
            ready = None
            if t.ready[side] is not None:
                ready = qa.copy()
                ready[t.arm_only[side]] = t.ready[side][t.arm_only[side]]
                ready[t.jaw[side]] = qa[t.jaw[side]]
                candidates.append([qa, ready, qb])
            up_a, up_b = self._lifted(qa, side, rng), self._lifted(qb, side, rng)
            if up_a is not None:
                candidates.append([qa, up_a, qb])
            if up_b is not None:
                candidates.append([qa, up_b, qb])
            if up_a is not None and up_b is not None:
                candidates.append([qa, up_a, up_b, qb])
            over = self._over_middle(qa, qb, side, rng)
            if over is not None:
                candidates.append([qa, over, qb])
                if up_a is not None and up_b is not None:
                    candidates.append([qa, up_a, over, up_b, qb])
            if ready is not None and up_b is not None:
                candidates.append([qa, ready, up_b, qb])
            if ready is not None and up_a is not None:
                candidates.append([qa, up_a, ready, qb])
        # shortest first in the time metric (the time the path takes at the velocity limits): the first valid one is
        # the quickest of the simple motions (a stable sort keeps the order above among equals)
        weights = 1.0 / t.robot.velocity_limit
        candidates.sort(key=lambda w: path_length(np.array(w), weights))
        for waypoints in candidates:
            if self._path_valid(waypoints, validity):
                return np.array(waypoints)
        return None

    def _lifted(self, q: np.ndarray, side: Side, rng: np.random.Generator) -> np.ndarray | None:
        """``q`` with ``side``'s hand raised by ``via_lift_m`` (arm-only IK from q), or None."""
        T = self.task.tcp(q, side)
        T[2, 3] += self.task.settings.via_lift_m
        return self._arm_at(T, q, side, q, rng)

    def _over_middle(self, qa: np.ndarray, qb: np.ndarray, side: Side, rng: np.random.Generator) -> np.ndarray | None:
        """The joint-space middle of qa and qb with ``side``'s hand raised ``via_lift_m`` above the higher of the
        two ends (arm-only IK from the middle), or None: a via posture near the straight line that clears what the
        straight line itself hits (mostly the table under the hand)."""
        t = self.task
        mid = 0.5 * (qa + qb)
        T = t.tcp(mid, side)
        T[2, 3] = max(T[2, 3], t.tcp(qa, side)[2, 3], t.tcp(qb, side)[2, 3]) + t.settings.via_lift_m
        return self._arm_at(T, mid, side, qa, rng)

    def _arm_at(self, T: np.ndarray, q_from: np.ndarray, side: Side, jaw_from: np.ndarray,
                rng: np.random.Generator) -> np.ndarray | None:
        """``side``'s hand at T by arm-only IK from (and resting at) ``q_from``, its jaw as in ``jaw_from``; None when
        the IK finds no solution."""
        t = self.task
        res = t.ik_arm_only.solve_arm(side, T, q_from, rng, rest_q=q_from)
        self.data.counters["ik_solves"] += 1
        if res.q is None:
            return None
        out = res.q
        out[t.jaw[side]] = jaw_from[t.jaw[side]]
        return out

    def _path_valid(self, waypoints: list[np.ndarray], validity) -> bool:
        res = self.task.settings.trrt.edge_resolution_rad
        states = [waypoints[0][None]]
        for a, b in zip(waypoints[:-1], waypoints[1:]):
            n = max(int(np.ceil(np.abs(b - a).max() / res)), 1)
            f = np.linspace(0.0, 1.0, n + 1)[1:, None]
            states.append(a[None] * (1 - f) + b[None] * f)
        ok, _ = validity(np.vstack(states))
        return bool(np.all(ok))

    def timed(self, piece: MotionPiece) -> MotionPiece | None:
        """Time a piece; None if the ZMP or the dense margin check cannot be kept."""
        t = self.task
        timed = time_path(piece.waypoints, t.robot, t.evaluator, piece.hold, t.settings.timing,
                          threshold_m=t.evaluator.threshold_m if t.constrained else -np.inf)
        if not timed.ok:
            return None
        piece.path = piece.waypoints
        piece.waypoints = timed.Q
        piece.timed = True  # type: ignore[attr-defined]
        return piece

    def validate_hop(self, a, b, kind: str) -> Validation:
        t = self.task
        rng = np.random.default_rng(t.hop_seed(a, b, kind))
        pieces: list[MotionPiece] = []
        if a is None:  # home -> first node's pre-grasp
            kp = self.keyposes[b]
            path = self.motion(t.home, kp.q_pre, t.active[b.hand], None, kp.T_obj, None, rng)
            if path is None:
                return Validation(False, FailureCause.MOTION, "home to the first pre-grasp")
            pieces.append(MotionPiece("transit", b.hand, path, "none", None))
        elif b is None:  # last node: release, retreat, home
            kp = self.keyposes[a]
            path = self.motion(kp.q_pre, self.home_from(kp.q_pre, a.hand), t.active[a.hand], None, kp.T_obj, None, rng)
            if path is None:
                return Validation(False, FailureCause.MOTION, "back home after placing")
            pieces.append(MotionPiece("transit", a.hand, path, "none", None))
        elif kind == "transit":  # regrasp at the same placement
            ka, kb = self.keyposes[a], self.keyposes[b]
            path = self.motion(ka.q_pre, self.with_arm_of(kb.q_pre, ka.q_pre, b.hand), t.active[b.hand], None, ka.T_obj, None, rng)
            if path is None:
                return Validation(False, FailureCause.MOTION, "regrasp transit")
            pieces.append(MotionPiece("transit", b.hand, path, "none", None))
        elif kind == "transfer":
            ka, kb = self.keyposes[a], self.keyposes[b]
            hold = HoldSpec(a.hand, ka.T_obj_tcp)
            path = self.motion(ka.q_lift, self.with_arm_of(kb.q_lift, ka.q_lift, a.hand), t.active[a.hand], hold, None, None, rng)
            if path is None:
                return Validation(False, FailureCause.MOTION, "transfer between placements")
            pieces.append(MotionPiece("transfer", a.hand, path, a.hand, hold))
        elif kind == "handover" and isinstance(b, HandoverNode):
            ka, hp = self.keyposes[a], self.handovers[b]
            if not self.plan_handover_motions(b):
                return Validation(False, FailureCause.MOTION, "handover transits", remove_node=True)
            hold = HoldSpec(a.hand, ka.T_obj_tcp)
            cause, _ = self.data.checker.classify(hp.q_giver_at, hold, None)
            if cause:
                return Validation(False, cause, "giver at the handover with its own grasp")
            path = self.motion(ka.q_lift, hp.q_giver_at, t.active[a.hand], hold, None, None, rng)
            if path is None:
                return Validation(False, FailureCause.MOTION, "transfer to the handover pose")
            pieces.append(MotionPiece("transfer", a.hand, path, a.hand, hold))
        elif kind == "handover":  # handover node -> placement node of the taker
            hp, kb = self.handovers[a], self.keyposes[b]
            hold = HoldSpec(b.hand, hp.T_taker_obj_tcp)
            target = self.with_arm_of(kb.q_lift, hp.q_after, b.hand)
            cause, _ = self.data.checker.classify(target, hold, None)
            if cause:
                return Validation(False, cause, "taker at the lift pose with the handover grasp")
            path = self.motion(hp.q_after, target, t.active[b.hand], hold, None, None, rng)
            if path is None:
                return Validation(False, FailureCause.MOTION, "transfer from the handover to the goal")
            pieces.append(MotionPiece("transfer", b.hand, path, b.hand, hold))
        else:  # pragma: no cover - the graph only makes the kinds above
            return Validation(False, FailureCause.MOTION, f"unknown edge kind {kind}")
        timed = []
        for p in pieces:
            tp = self.timed(p)
            if tp is None:
                return Validation(False, FailureCause.COM_MARGIN if t.constrained else FailureCause.MOTION, "timing: ZMP or dense margin")
            timed.append(tp)
        return Validation(True, payload=timed)

    def plan_handover_motions(self, node: HandoverNode) -> bool:
        """Plan the taker's way to its pre-grasp and the giver's way home (arm only, waist fixed)."""
        hp = self.handovers[node]
        if hp.motions_planned:
            return True
        t = self.task
        rng = np.random.default_rng([*t.node_seed(node), len(HOP_KINDS)])  # the node's, whichever hop plans them
        for i, piece in ((0, hp.pieces[0]), (5, hp.pieces[5])):
            side = node.taker if i == 0 else node.giver
            qa, qb = piece.waypoints[0], piece.waypoints[-1]
            path = self.motion(qa, qb, t.arm_only[side], piece.hold, None, None, rng)
            if path is None:
                return False
            piece.waypoints = path
        hp.motions_planned = True
        return True

    def with_arm_of(self, q_target: np.ndarray, q_current: np.ndarray, side: Side) -> np.ndarray:
        """q_target for the waist and ``side``'s arm and jaw; everything else as in q_current."""
        out = q_current.copy()
        idx = self.task.active[side]
        out[idx] = q_target[idx]
        out[self.task.jaw[side]] = q_target[self.task.jaw[side]]
        return out

    def home_from(self, q: np.ndarray, side: Side) -> np.ndarray:
        out = q.copy()
        out[self.task.active[side]] = self.task.home[self.task.active[side]]
        return out

