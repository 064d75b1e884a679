"""Batched probes of a task's nodes before the search validates them one by one.

The search weighs nodes by what the probes find (the margin of holding the object at a grasp),
and drops those whose verdict they already know: the held object unstable at the grasp, the jaw
closing into the table, the giver of a handover unable to reach or unstable. Each probe is a
batched IK descent over many nodes at once, then the state evaluator and the collision screen on
the whole batch; the outcomes go into the search's data (``grasp_probes``, ``giver_at``,
``node_cache`` of :class:`~planner.regrasp.search_data.SearchData`), exactly as the one-by-one
validation would find them first. The task itself is only read.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from planner.errors import Canceled
from planner.grasping.grasps import Grasp
from planner.motion.ik_batch import BatchIkResult
from planner.regrasp.failure_cause import FailureCause
from planner.regrasp.graph import HandoverNode, PlacementNode, Validation
from planner.regrasp.results import GraspProbe
from planner.regrasp.settings import HANDS_INDEX, Side
from planner.regrasp.search_data import SearchData, stable_posture
from planner.array_keys import array_key
from planner.regrasp.task import Task
from planner.stability.evaluator import HoldSpec
from planner.termination import never
from planner.transforms import inverse


def probe_grasps(task: Task, data: SearchData, nodes: list[PlacementNode],
                 canceled: Callable[[], bool] = never) -> dict[PlacementNode, GraspProbe]:
    """The IK solution at each node's grasp pose and the CoM margin of holding the object there, for
    the nodes not probed yet: batched descents per hand (:mod:`planner.motion.ik_batch`).

    ``canceled`` is polled between the nodes' stable-posture searches (thousands on a large task): when it
    asks, :class:`~planner.errors.Canceled` is raised and the hand's batch under way leaves nothing in ``data``.

    The search weighs nodes by these margins before validating any: they bound a node's validated
    margin from above (its lift starts from this very state), so the cheapest path stays the
    cheapest once validated far more often than with the home-posture guess, and the search
    validates a few nodes where it validated every grasp of the start and goal placements.
    """
    todo = [n for n in dict.fromkeys(nodes) if n not in data.grasp_probes]
    for side in ("left", "right"):
        mine = [n for n in todo if n.hand == side]
        if not mine:
            continue
        T_obj, targets = _grasp_targets(task, side, mine)
        res = _batch_arm_ik(task, data, side, targets, [task.node_seed(n) for n in mine])
        _record_probes(task, data, side, mine, T_obj, res, task.arm_only[side], canceled)
    return data.grasp_probes


def probe_grasps_with_waist(task: Task, data: SearchData, side: Side, canceled: Callable[[], bool] = never) -> None:
    """For every placement node of ``side`` whose probe missed (the arm alone did not reach) and
    that has no verdict yet: one batched descent with the waist helping, from home, then the same
    margin and jaw-closing probes; a node's validation starts from the posture found.

    Called when a search first validates such a node. Those nodes come last in the search (no
    margin, the highest cost), so most searches never get there; one that does (a configuration
    with no key path) would otherwise validate them by the dozen, one by one, most failing on the
    margin at the grasp. ``canceled``: as in :func:`probe_grasps`."""
    mine = [n for n, p in data.grasp_probes.items()
            if p.q is None and n.hand == side and n not in data.waist_probed and n not in data.node_cache]
    if not mine:
        return
    T_obj, targets = _grasp_targets(task, side, mine)
    res = _batch_from_home(task, data, "waist", side, targets)
    data.counters["ik_solves"] += len(mine)
    reached = np.flatnonzero(res.ok)
    if reached.size:
        _record_probes(task, data, side, [mine[k] for k in reached], T_obj[reached], res.take(reached), task.active[side],
                       canceled)
    data.waist_probed.update(mine)


def _grasp_targets(task: Task, side: Side, nodes: list[PlacementNode]) -> tuple[np.ndarray, np.ndarray]:
    """The resting object's poses (N, 4, 4) at ``nodes`` and ``side``'s TCP targets (N, 4, 4) there."""
    T_obj = np.array([task.placements[n.placement] for n in nodes])
    return T_obj, T_obj @ np.array([task.grasps[side][n.grasp].T_obj_tcp for n in nodes])


def _record_probes(task: Task, data: SearchData, side: Side, nodes: list[PlacementNode], T_obj: np.ndarray, res: BatchIkResult,
                   moving: np.ndarray, canceled: Callable[[], bool]) -> None:
    """Store the probes of ``nodes`` from their batched IK (``moving``: the columns it moved), with the
    margin of holding the object at the grasp; cache the verdicts the validation would reach first. The
    probes are stored once all are found, so a cancel (``canceled``, polled per node) leaves none."""
    grasps = task.grasps[side]
    Q = res.q.copy()
    task.put_jaw(Q, side, [grasps[n.grasp].jaw_value for n in nodes])
    robot_com = task.evaluator.evaluate(Q, active=[*moving, *task.jaw[side]]).robot_com
    held = task.evaluator.with_object(robot_com, T_obj)  # the object stays where it rests
    data.counters["com_states"] += len(nodes)
    probes: dict[PlacementNode, GraspProbe] = {}
    unstable: list[PlacementNode] = []
    for k, n in enumerate(nodes):
        q, margin = (res.q[k], float(held.margin[k])) if res.ok[k] else (None, None)
        if res.ok[k] and not held.stable[k] and task.constrained:
            if canceled():
                raise Canceled()
            # Exactly what the node's validation would find first, from the same state: the nearest
            # posture that holds the object there with the margin kept, or the node fails the margin.
            q_stable = stable_posture(task, data, Q[k], (side,), T_obj[k])
            if q_stable is None:
                unstable.append(n)
            else:
                q, margin = q_stable, task.evaluator.evaluate_one(q_stable, _hold_at(task, side, q_stable, T_obj[k])).margin
        probes[n] = GraspProbe(q, margin)
    for n in unstable:
        data.node_cache.setdefault(n, Validation(False, FailureCause.COM_MARGIN, "holding the object at the grasp pose"))
    data.grasp_probes.update(probes)
    _probe_jaw_closing(task, data, side, [n for k, n in enumerate(nodes) if res.ok[k] and n not in data.node_cache], grasps)


def _hold_at(task: Task, side: Side, q: np.ndarray, T_obj: np.ndarray) -> HoldSpec:
    """``side`` holding the object at ``T_obj`` from posture ``q``."""
    return HoldSpec(side, inverse(T_obj) @ task.tcp(q, side))


def _probe_jaw_closing(task: Task, data: SearchData, side: Side, nodes: list[PlacementNode], grasps: list[Grasp]) -> None:
    """The node validation's second check, batched over probed nodes: the jaw closing on the resting
    object from the probe's posture (three states, robot alone for the margin, the object where it
    rests for collision, ``side``'s fingers allowed to touch it). A failure is cached as the
    validation's own verdict: many placement validations fail here, and one by one each would cost
    a search."""
    if not nodes:
        return
    jaw = task.jaw[side]
    q_open = np.array([data.grasp_probes[n].q for n in nodes])
    q_open[:, jaw] = task.robot.upper[jaw]
    q_closed = q_open.copy()
    task.put_jaw(q_closed, side, [grasps[n.grasp].jaw_value for n in nodes])
    s = np.linspace(0.0, 1.0, 3)[None, :, None]  # :func:`planner.motion.interpolation.interpolate` with three states, per node
    Q = (q_open[:, None] * (1 - s) + q_closed[:, None] * s).reshape(-1, task.robot.nq)
    T_obj = np.repeat(np.array([task.placements[n.placement] for n in nodes]), 3, axis=0)
    causes, margins = data.checker.classify_groups(Q, len(nodes), None, T_obj, grasping=side)
    for n, cause, margin in zip(nodes, causes, margins):
        if cause:
            data.node_cache[n] = Validation(False, cause, "closing the jaw", margin_m=float(margin))


def probe_givers(task: Task, data: SearchData, nodes: list[HandoverNode], canceled: Callable[[], bool] = never) -> None:
    """The giver alone at each handover pose (the search's ``giver_at``), for the (pose, giver grasp) pairs
    of ``nodes`` not known yet, in batches: arm-only IK, margin and collisions holding the object.

    Most handover nodes fail right there (the giver's arm or the object against the body), so a
    batch spares a one-by-one solve per pair. Where the arm alone misses (the same two attempts as the
    one-by-one solve), the node's validation lets the waist help. Where the posture found collides (the
    upper arm or forearm against the chest or the object: the elbow the descent from home chose), up to
    ``handover_giver_postures`` more descents from starts drawn for that pair are tried, in batches, and the
    first posture that passes is kept: the arm is redundant, and another elbow often clears. ``canceled`` is
    polled between the givers' stable-posture searches; a cancel raises :class:`~planner.errors.Canceled` before
    that hand's batch is stored (but for the pairs whose arm missed, already known)."""
    keys = [k for k in dict.fromkeys((n.pose, n.giver_grasp, n.giver) for n in nodes) if k not in data.giver_at]
    for side in ("left", "right"):
        mine = [k for k in keys if k[2] == side]
        if not mine:
            continue
        grasps = task.grasps[side]
        T_obj = np.array([data.handover_poses(task)[k[0]].T_world_obj for k in mine])
        targets = T_obj @ np.array([grasps[k[1]].T_obj_tcp for k in mine])
        res = _batch_arm_ik(task, data, side, targets, [[task.seed, 2, k[0], k[1], HANDS_INDEX[side]] for k in mine])
        for k in np.flatnonzero(~res.ok):
            data.giver_at[mine[k]] = None  # the same two attempts the one-by-one solve makes missed
        ok = np.flatnonzero(res.ok)
        found = check_givers(task, data, side, [mine[k] for k in ok], res.q[ok], T_obj[ok], canceled)
        colliding = [k for k in ok if found[mine[k]][2] == FailureCause.COLLISION]
        found.update(_other_givers(task, data, side, [mine[k] for k in colliding], T_obj[colliding],
                                   targets[colliding], canceled))
        data.giver_at.update(found)


def check_givers(task: Task, data: SearchData, side: Side, keys: list, Q: np.ndarray, T_obj: np.ndarray,
                 canceled: Callable[[], bool]) -> dict:
    """``key -> (q, hold, cause, margin)`` of the giver in each posture of ``Q`` holding the object at ``T_obj``
    (jaw closed on the key's grasp): collisions and the margin, a margin failure given its steadied posture
    (:func:`steady_giver`)."""
    if not keys:
        return {}
    grasps = task.grasps[side]
    Q = Q.copy()
    task.put_jaw(Q, side, [grasps[k[1]].jaw_value for k in keys])
    tcp = task.robot.spec.arms[side].tcp
    robot_com, frames = task.world.kin.com_and_frames(task.stance.base_pose, Q, [tcp])
    R, p = frames[tcp]
    T_tcp = np.zeros((len(keys), 4, 4))
    T_tcp[:, :3, :3], T_tcp[:, :3, 3], T_tcp[:, 3, 3] = R, p, 1.0
    held = task.evaluator.with_object(robot_com, T_obj)
    collides = task.world.check_batch(task.stance.base_pose, Q, held=[(side, np.eye(4))],
                                      held_object_poses=T_obj).collides
    data.counters["com_states"] += len(keys)
    data.counters["collision_states"] += len(keys)
    found: dict = {}
    for row, key in enumerate(keys):
        hold = HoldSpec(side, inverse(T_obj[row]) @ T_tcp[row])
        if task.constrained and not held.stable[row]:
            if canceled():
                raise Canceled()
            found[key] = steady_giver(task, data, side, Q[row], hold, T_obj[row])
        else:
            found[key] = (Q[row], hold, FailureCause.COLLISION if collides[row] else None, float(held.margin[row]))
    return found


def _other_givers(task: Task, data: SearchData, side: Side, keys: list, T_obj: np.ndarray, targets: np.ndarray,
                  canceled: Callable[[], bool]) -> dict:
    """For givers whose first posture collides: the first of up to ``handover_giver_postures`` more postures that
    passes, each round a batched descent from a start drawn for each key (its own generator: the verdict does not
    depend on which other keys share the batch)."""
    out: dict = {}
    ik = task.ik_arm_only
    cols = ik.batch.active_columns(side)
    rngs = [np.random.default_rng([task.seed, 2, k[0], k[1], HANDS_INDEX[side], 1]) for k in keys]
    todo = np.arange(len(keys))
    for attempt in range(2, 2 + task.settings.handover_giver_postures):
        if not todo.size:
            break
        starts = np.array([ik.attempt_start(attempt, task.home, cols, rngs[k]) for k in todo])
        res = ik.batch.solve(side, targets[todo], task.stance.base_pose, starts, task.home)
        data.counters["ik_solves"] += len(todo)
        data.counters["giver_postures_tried"] += len(todo)
        reached = todo[res.ok]
        checked = check_givers(task, data, side, [keys[k] for k in reached], res.q[res.ok], T_obj[reached], canceled)
        passed = {k for k in reached if checked[keys[k]][2] is None}
        out.update({keys[k]: checked[keys[k]] for k in passed})
        data.counters["giver_postures_rescued"] += len(passed)
        todo = np.array([k for k in todo if k not in passed], dtype=int)
    return out


def steady_giver(task: Task, data: SearchData, side: Side, q: np.ndarray, hold: HoldSpec, T_obj: np.ndarray) -> tuple:
    """The giver holding the object at a handover pose, checked: ``(q, hold, cause, margin)``. Where the
    posture fails the margin, the nearest posture that keeps the hand there and the margin (the waist
    leaning back) is checked instead."""
    cause, margin = data.checker.classify(q, hold, None)
    if cause == FailureCause.COM_MARGIN:
        q_stable = stable_posture(task, data, q, (side,), T_obj)
        if q_stable is not None:
            q, (cause, margin) = q_stable, data.checker.classify(q_stable, hold, None)
    return q, hold, cause, margin


def _batch_from_home(task: Task, data: SearchData, solver: str, side: Side, targets: np.ndarray) -> BatchIkResult:
    """The batched IK of ``side`` to ``targets`` from home by the arm-only or the waist-and-arm solver: it draws
    nothing, so the search's shared seed-free results keep it (:mod:`planner.regrasp.seed_free`)."""
    ik = task.ik_arm_only if solver == "arm_only" else task.ik

    def solve() -> BatchIkResult:
        return ik.batch.solve(side, targets, task.stance.base_pose, task.home, task.home)

    if data.seed_free is None:
        return solve()
    return data.seed_free.batch_ik((solver, side, *array_key(targets)), solve)


def _batch_arm_ik(task: Task, data: SearchData, side: Side, targets: np.ndarray, seeds: list) -> BatchIkResult:
    """:func:`planner.regrasp.search_data.solve_ik` with the arm alone for many targets at once: the attempt from home, then,
    where it missed, the first restart from the draw the one-by-one solve would make with the
    generator seeded by ``seeds[k]``."""
    res = _batch_from_home(task, data, "arm_only", side, targets)
    data.counters["ik_solves"] += len(targets)
    missed = np.flatnonzero(~res.ok)
    if missed.size and task.ik_arm_only.settings.restarts > 0:
        cols = task.ik_arm_only.batch.active_columns(side)
        starts = np.array([task.ik_arm_only.attempt_start(1, task.home, cols, np.random.default_rng(seeds[k])) for k in missed])
        again = task.ik_arm_only.batch.solve(side, targets[missed], task.stance.base_pose, starts, task.home)
        res.q[missed], res.ok[missed] = again.q, again.ok
    return res


