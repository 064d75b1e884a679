"""Validation of the regrasp graph's nodes: the key poses of a placement node and of a handover.

A placement node (an object placement, a grasp and a hand) is valid when its grasp, lift and
pre-grasp poses are IK-feasible, and the moves between them (approach, closing the jaw, lift)
are collision-free and keep the CoM margin. A handover node (a floating pose and a grasp pair)
is valid when the giver can hold the object there, the taker can approach and close its jaw,
and the giver can release and retreat, each move collision-free and stable. Cheapest decisive
checks first; a failure names its cause (ik, collision, com_margin) and where it happened.
A key posture that fails the CoM margin is first replaced by the nearest one that keeps the hands
where they are and the margin (:func:`planner.regrasp.search_data.stable_posture`: the waist leans back, the arm
re-poses); only when there is none does the node fail the margin.
Each node draws from its own generator, so a verdict does not depend on the search order. The task is
only read; what a validation learns on the way (the giver alone at a handover pose, counters) goes into
the search's :class:`~planner.regrasp.search_data.SearchData`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from planner.motion.ik import key_pose_targets
from planner.regrasp.failure_cause import FailureCause
from planner.regrasp.graph import HandoverNode, PlacementNode, Validation
from planner.regrasp.plan_assembly import MotionPiece
from planner.regrasp.probes import check_givers, probe_givers, probe_grasps_with_waist
from planner.regrasp.results import HandoverPoses, KeyPoses
from planner.regrasp.search_data import SearchData, solve_ik, solve_targets, stable_posture
from planner.regrasp.task import Task
from planner.stability.evaluator import HoldSpec
from planner.termination import never
from planner.transforms import inverse


def validate_placement(task: Task, data: SearchData, node: PlacementNode, rng: np.random.Generator,
                       canceled: Callable[[], bool] = never) -> Validation:
    """The verdict on a placement node (its key poses when valid). ``canceled`` is polled inside the one long step,
    the batch probe with the waist helping (:func:`planner.regrasp.probes.probe_grasps_with_waist`)."""
    t, d, s = task, data, task.settings
    side = node.hand
    grasp = t.grasps[side][node.grasp]
    T_obj = t.placements[node.placement]
    T_grasp = T_obj @ grasp.T_obj_tcp
    targets = key_pose_targets(T_grasp, approach_m=s.pregrasp_m, lift_m=s.lift_m)
    T_pre, T_lift = targets["pregrasp"], targets["lift"]
    # Cheapest decisive checks first: the grasp pose, then the held object there, then lift, then pre-grasp.
    probe = d.grasp_probes.get(node)
    if probe is not None and probe.q is None and node not in d.waist_probed:
        probe_grasps_with_waist(t, d, side, canceled)
        v = d.node_cache.get(node)
        if v is not None:
            return v  # the batch found what this validation would find first
        probe = d.grasp_probes[node]
    q_grasp = probe.q.copy() if probe is not None and probe.q is not None else solve_ik(t, d, side, T_grasp, t.home, rng)
    if q_grasp is None:
        return Validation(False, FailureCause.IK, "grasp pose out of reach")
    q_grasp[t.jaw[side]] = t.robot.upper[t.jaw[side]]
    q_closed = q_grasp.copy()
    q_closed[t.jaw[side]] = grasp.jaw_value
    T_obj_tcp = inverse(T_obj) @ t.tcp(q_closed, side)
    hold = HoldSpec(side, T_obj_tcp)
    if t.constrained and not t.evaluator.evaluate_one(q_closed, hold).stable:
        q_stable = stable_posture(t, d, q_closed, (side,), T_obj)
        if q_stable is None:
            return Validation(False, FailureCause.COM_MARGIN, "holding the object at the grasp pose")
        q_closed = q_stable
        q_grasp = q_stable.copy()
        q_grasp[t.jaw[side]] = t.robot.upper[t.jaw[side]]
    cause, m2 = d.checker.classify(t.line(q_grasp, q_closed, 3), None, T_obj, grasping=side)
    if cause:
        return Validation(False, cause, "closing the jaw", margin_m=m2)
    q_lift = solve_ik(t, d, side, T_lift, q_grasp, rng)
    if q_lift is None:
        return Validation(False, FailureCause.IK, "lift pose out of reach")
    q_lift[t.jaw[side]] = grasp.jaw_value
    if t.constrained and not t.evaluator.evaluate_one(q_lift, hold).stable:
        q_lift = stable_posture(t, d, q_lift, (side,), t.tcp(q_lift, side) @ hold.T_tcp_obj)
        if q_lift is None:
            return Validation(False, FailureCause.COM_MARGIN, "holding the object at the lift pose")
    cause, m3 = d.checker.classify(t.line(q_closed, q_lift), hold, None)
    if cause:
        return Validation(False, cause, "lift", margin_m=m3)
    q_pre = solve_ik(t, d, side, T_pre, q_grasp, rng)
    if q_pre is None:
        return Validation(False, FailureCause.IK, "pre-grasp pose out of reach")
    q_pre[t.jaw[side]] = t.robot.upper[t.jaw[side]]
    cause, m1 = d.checker.classify(np.vstack([q_pre[None], t.line(q_pre, q_grasp)]), None, T_obj, grasping=side)
    if cause:
        return Validation(False, cause, "approach", margin_m=m1)
    kp = KeyPoses(q_pre=q_pre, q_grasp_open=q_grasp, q_grasp=q_closed, q_lift=q_lift, T_obj=T_obj,
                  T_obj_tcp=T_obj_tcp, margin=min(m1, m2, m3))
    return Validation(True, margin_m=kp.margin, payload=kp)


def validate_handover(task: Task, data: SearchData, node: HandoverNode, rng: np.random.Generator) -> Validation:
    """The verdict on a handover node (the exchange's motions when valid). Where the exchange collides with the
    giver posed as first solved (the taker's hand or arm against the giver's), up to ``handover_giver_postures``
    more giver postures are tried: the giver's IK from starts the node's generator draws (home perturbed, then a
    uniform draw within the limits, alternately; a start that leads back to the first posture is skipped). The arm
    is redundant, and the elbow the first solve finds can leave the taker's hand no way in. The first posture
    whose exchange passes is kept; the first verdict is returned when none does."""
    t, d = task, data
    giver = node.giver
    gg = t.grasps[giver][node.giver_grasp]
    T_obj = d.handover_poses(t)[node.pose].T_world_obj
    T_g = T_obj @ gg.T_obj_tcp
    # Arms without the waist first: a turning waist swings the idle arm into the table. With the
    # waist still the arms are independent, so the giver is solved and checked alone, once per
    # (pose, giver grasp), by the probe (the search probes all its nodes' givers before it starts): most
    # handover nodes fail there (the object or the giver's arm against the body), and the pairs of a pose
    # share their giver grasps.
    giver_key = (node.pose, node.giver_grasp, giver)
    if giver_key not in d.giver_at:
        probe_givers(t, d, [node])
    given = d.giver_at[giver_key]
    first = _handover_from(t, d, node, given, rng)
    if first.ok or first.cause != FailureCause.COLLISION or given is None or given[2] is not None:
        return first  # not a collision, or the giver's first posture itself failed (the probes drop those nodes)
    q_first = given[0]
    active = t.ik_arm_only.active_indices((giver,))
    for attempt in range(1, t.settings.handover_giver_postures + 1):
        q_g = solve_ik(t, d, giver, T_g, t.ik_arm_only.attempt_start(attempt, t.home, active, rng), rng, arm_only=True)
        if q_g is None or np.abs(q_g[active] - q_first[active]).max() < 1e-3:
            continue  # out of reach from there, or the first posture again
        checked = _checked_giver(t, d, node, q_g, T_obj)
        if checked[2] is None:
            d.counters["handover_giver_postures"] += 1
            v = _handover_from(t, d, node, checked, rng)
            if v.ok:
                return v
    return first


def _checked_giver(t: Task, d: SearchData, node: HandoverNode, q_g: np.ndarray, T_obj: np.ndarray) -> tuple:
    """The giver alone at the handover pose in posture ``q_g`` (jaw closed on its grasp), checked: ``(q, hold,
    cause, margin)`` (:func:`planner.regrasp.probes.check_givers`)."""
    key = (node.pose, node.giver_grasp, node.giver)
    return check_givers(t, d, node.giver, [key], q_g[None], T_obj[None], never)[key]


def _handover_from(t: Task, d: SearchData, node: HandoverNode, checked: tuple | None,
                   rng: np.random.Generator) -> Validation:
    """The verdict on a handover node with the giver posed as ``checked`` (None: the arm alone did not reach;
    both arms and the waist are then solved together)."""
    giver, taker = node.giver, node.taker
    gg, tg = t.grasps[giver][node.giver_grasp], t.grasps[taker][node.taker_grasp]
    T_obj = d.handover_poses(t)[node.pose].T_world_obj
    T_g = T_obj @ gg.T_obj_tcp
    T_t = T_obj @ tg.T_obj_tcp
    q_both = None
    if checked is not None:
        q_g, hold_g, cause, m0 = checked
        if cause:
            return Validation(False, cause, "giver at the handover pose", margin_m=m0)
        q_t = solve_ik(t, d, taker, T_t, q_g, rng, arm_only=True)
        if q_t is not None:
            q_both = q_g.copy()
            q_both[t.arm_only[taker]] = q_t[t.arm_only[taker]]
    if q_both is None:
        # Both arms with the waist, which they share.
        d.counters["ik_solves"] += 1
        q_both = solve_targets(t, d, "waist", {giver: T_g, taker: T_t}, t.home, rng)
        if q_both is None:
            return Validation(False, FailureCause.IK, "handover pose out of reach for both hands")
        q_both[t.jaw[giver]] = gg.jaw_value
        hold_g = HoldSpec(giver, inverse(T_obj) @ t.tcp(q_both, giver))
        q_g = q_both.copy()
        q_g[t.arm_only[taker]] = t.home[t.arm_only[taker]]
        cause, m0 = d.checker.classify(q_g, hold_g, None)
        if cause:
            return Validation(False, cause, "giver at the handover pose", margin_m=m0)
    q_both[t.jaw[taker]] = t.robot.upper[t.jaw[taker]]
    v = _exchange(t, d, node, q_g, hold_g, m0, q_both, rng)
    if v.ok or (v.cause, v.detail) != (FailureCause.COM_MARGIN, "taker approach"):
        return v
    # The taker's arm reaching out costs the margin the giver kept: the nearest posture of the waist and
    # both arms with both hands where they are and the margin kept, and the giver's part again from it.
    q_stable = stable_posture(t, d, q_both, (giver, taker), T_obj)
    if q_stable is None:
        return v
    q_g = q_stable.copy()
    q_g[t.arm_only[taker]] = t.home[t.arm_only[taker]]
    cause, m0 = d.checker.classify(q_g, hold_g, None)
    if cause:
        return Validation(False, cause, "giver at the handover pose, steadied for the exchange", margin_m=m0)
    return _exchange(t, d, node, q_g, hold_g, m0, q_stable, rng)


def _exchange(t: Task, d: SearchData, node: HandoverNode, q_giver_at: np.ndarray, hold_g: HoldSpec, m0: float, q_both: np.ndarray,
              rng: np.random.Generator) -> Validation:
    """A handover from the giver at the handover pose (``q_giver_at``, holding as ``hold_g``, margin ``m0``)
    to both hands on the object (``q_both``, the taker's jaw open): the taker's approach and closing, the
    exchange, the giver's retreat, each move checked."""
    s = t.settings
    giver, taker = node.giver, node.taker
    gg, tg = t.grasps[giver][node.giver_grasp], t.grasps[taker][node.taker_grasp]
    T_obj = d.handover_poses(t)[node.pose].T_world_obj
    T_g = T_obj @ gg.T_obj_tcp
    T_t = T_obj @ tg.T_obj_tcp
    G_g = hold_g.T_obj_tcp
    T_pre_t = key_pose_targets(T_t, approach_m=s.pregrasp_m)["pregrasp"]
    q_taker_pre = solve_ik(t, d, taker, T_pre_t, q_both, rng, arm_only=True)
    if q_taker_pre is None:
        return Validation(False, FailureCause.IK, "taker pre-grasp out of reach")
    q_taker_pre[t.jaw[taker]] = t.robot.upper[t.jaw[taker]]
    T_pre_g = key_pose_targets(T_g, approach_m=s.pregrasp_m)["pregrasp"]
    q_giver_pre = solve_ik(t, d, giver, T_pre_g, q_both, rng, arm_only=True)
    if q_giver_pre is None:
        return Validation(False, FailureCause.IK, "giver retreat out of reach")
    # Taker: home -> pre-grasp (T-RRT, arm only), approach, close.
    q_taker_pre_full = q_giver_at.copy()
    q_taker_pre_full[t.arm_only[taker]] = q_taker_pre[t.arm_only[taker]]
    approach_end = q_both.copy()
    cause, m1 = d.checker.classify(t.line(q_taker_pre_full, approach_end), hold_g, None, grasping=taker)
    if cause:
        return Validation(False, cause, "taker approach", margin_m=m1)
    q_both_closed = approach_end.copy()
    q_both_closed[t.jaw[taker]] = tg.jaw_value
    G_t = inverse(T_obj) @ t.tcp(q_both_closed, taker)
    hold_both = HoldSpec("both", G_g if giver == "left" else G_t)
    hold_t = HoldSpec(taker, G_t)
    q_released = q_both_closed.copy()
    q_released[t.jaw[giver]] = t.robot.upper[t.jaw[giver]]
    cause, m2 = d.checker.classify(t.line(q_both_closed, q_released, 3), hold_t, None, grasping=giver)
    if cause:
        return Validation(False, cause, "exchange", margin_m=m2)
    # Giver: retreat along its approach axis, then home (arm only).
    q_giver_back = q_released.copy()
    q_giver_back[t.arm_only[giver]] = q_giver_pre[t.arm_only[giver]]
    cause, m3 = d.checker.classify(t.line(q_released, q_giver_back), hold_t, None, grasping=giver)
    if cause:
        return Validation(False, cause, "giver retreat", margin_m=m3)
    q_after = q_giver_back.copy()
    q_after[t.arm_only[giver]] = t.home[t.arm_only[giver]]
    q_close_open = approach_end
    pieces = [
        MotionPiece("transit", taker, np.array([q_giver_at, q_taker_pre_full]), giver, hold_g),
        MotionPiece("approach", taker, t.line(q_taker_pre_full, q_close_open, 2), giver, hold_g),
        MotionPiece("handover", "both", t.line(q_close_open, q_both_closed, 2), giver, hold_g),
        MotionPiece("handover", "both", t.line(q_both_closed, q_released, 2), "both", hold_both),
        MotionPiece("retreat", giver, t.line(q_released, q_giver_back, 2), taker, hold_t),
        MotionPiece("transit", giver, np.array([q_giver_back, q_after]), taker, hold_t),
    ]
    hp = HandoverPoses(q_giver_at=q_giver_at, pieces=pieces, q_after=q_after, T_taker_obj_tcp=G_t,
                       margin=min(m0, m1, m2, m3))
    return Validation(True, margin_m=hp.margin, payload=hp)
