"""What a search learns about a task: the scratch of one plan or survey, apart from the task itself.

Like pinocchio's ``Data`` beside its ``Model``: the :class:`~planner.regrasp.task.Task` says what the
task is and never changes; a :class:`SearchData` holds what the search has worked out (node
validations, grasp probes, the givers alone at handover poses, the handover poses once computed),
its counters and timings, and the buffers its computations write into. The hand configurations of
one plan or survey share one, so a node validated for one configuration is not validated again for
another (its outcome does not depend on the configuration, and each node draws from its own
generator, so it does not depend on the order either).

The free functions here are the search's steps that need both: ``solve_ik(task, data, ...)`` and
``stable_posture(task, data, ...)``.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Sequence

import numpy as np

from planner.grasping.handover import HandoverPose
from planner.motion.stable_posture import PostureProblem, stable_posture as nearest_stable_posture
from planner.regrasp.graph import HandoverNode, PlacementNode
from planner.regrasp.results import GraspProbe
from planner.array_keys import array_key
from planner.regrasp.seed_free import SeedFreeResults
from planner.regrasp.settings import Side
from planner.regrasp.state_checker import StateChecker
from planner.regrasp.task import Task
from planner.regrasp.task_setup import task_handover_poses


class SearchData:
    """The scratch of one search over a task: ``SearchData(task)``. ``seed_free`` shares the results of the
    seed-free steps with searches of the same problem under other seeds (:mod:`planner.regrasp.seed_free`)."""

    def __init__(self, task: Task, seed_free: SeedFreeResults | None = None) -> None:
        #: Checks done in this search; a Counter, so that a helper process's counts add on (update adds).
        self.counters: Counter = Counter({"ik_solves": 0, "collision_states": 0, "com_states": 0})
        #: Seconds spent on what this search computed on first use (``handover_poses_s``, ...).
        self.timings: dict[str, float] = {}
        #: node -> its validation
        self.node_cache: dict[PlacementNode | HandoverNode, object] = {}
        #: (handover pose, giver grasp, giver) -> (q, hold, cause, margin) of the giver alone there,
        #: or None when its arm alone cannot reach
        self.giver_at: dict = {}
        #: placement node -> its grasp probe (see :func:`planner.regrasp.probes.probe_grasps`)
        self.grasp_probes: dict[PlacementNode, GraspProbe] = {}
        #: placement nodes whose probe missed and then let the waist help (:func:`planner.regrasp.probes.probe_grasps_with_waist`)
        self.waist_probed: set[PlacementNode] = set()
        #: validity and clearance of states, counting into :attr:`counters`
        self.checker = StateChecker(task.evaluator, task.world, task.stance.base_pose, task.constrained, self.counters,
                                    limits=task.limits)
        self.seed_free = seed_free
        #: pinocchio scratch of :func:`stable_posture`
        self.posture_data = task.robot.create_data()
        self._handover_poses: list[HandoverPose] | None = None

    @property
    def seed_free(self) -> SeedFreeResults | None:
        """Seed-free results shared with the searches of the same problem under other seeds (None: not shared)."""
        return self._seed_free

    @seed_free.setter
    def seed_free(self, shared: SeedFreeResults | None) -> None:
        self._seed_free = shared
        self.checker.seed_free = shared

    def handover_poses(self, task: Task) -> list[HandoverPose]:
        """The task's handover poses, computed on first use (single-arm plans never need them)."""
        if self._handover_poses is None:
            t0 = time.perf_counter()
            shared = self.seed_free.handover_poses if self.seed_free is not None else None
            self._handover_poses = shared if shared is not None else task_handover_poses(task)
            if self.seed_free is not None:
                self.seed_free.handover_poses = self._handover_poses
            self.timings["handover_poses_s"] = time.perf_counter() - t0
        return self._handover_poses

    @property
    def handover_poses_known(self) -> int:
        """How many handover poses this search has computed (0 before they are first needed)."""
        return len(self._handover_poses or [])

    def validations(self) -> dict:
        """What this search has worked out so far (for a worker process to hand back; see :meth:`adopt`):
        node validations, grasp probes, the givers alone at handover poses, the handover poses."""
        return {"nodes": dict(self.node_cache), "givers": dict(self.giver_at), "probes": dict(self.grasp_probes),
                "waist_probed": set(self.waist_probed),
                "handover_poses": self._handover_poses, "handover_poses_s": self.timings.get("handover_poses_s")}

    def adopt(self, validations: dict) -> None:
        """Take over what another search of the same task (a survey worker) worked out, so a plan after the
        survey does not repeat it. Outcomes do not depend on who computed them (each node draws from its
        own generator; handover poses are deterministic), so existing entries are kept as they are."""
        for k, v in validations["nodes"].items():
            self.node_cache.setdefault(k, v)
        for k, v in validations["givers"].items():
            self.giver_at.setdefault(k, v)
        for k, v in validations["probes"].items():
            mine = self.grasp_probes.get(k)
            if mine is None or (mine.q is None and v.q is not None):  # the other search's waist reached it
                self.grasp_probes[k] = v
        self.waist_probed |= validations["waist_probed"]
        if self._handover_poses is None and validations["handover_poses"] is not None:
            self._handover_poses = validations["handover_poses"]
            self.timings["handover_poses_s"] = validations["handover_poses_s"]


def solve_ik(task: Task, data: SearchData, side: Side, target: np.ndarray, seed: np.ndarray,
             rng: np.random.Generator, arm_only: bool = False) -> np.ndarray | None:
    """IK for one TCP target. The arm alone is tried first: bending the waist moves the heavy
    torso and costs CoM margin, so the waist joins only when the arm cannot reach."""
    data.counters["ik_solves"] += 1
    q = solve_targets(task, data, "arm_only", {side: target}, seed, rng)
    if q is None and not arm_only:
        data.counters["ik_solves"] += 1
        q = solve_targets(task, data, "waist", {side: target}, seed, rng)
    return q


def solve_targets(task: Task, data: SearchData, solver: str, targets: dict[Side, np.ndarray], seed: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray | None:
    """IK of ``targets`` by the task's arm-only (``"arm_only"``) or waist-and-arms (``"waist"``) solver from
    ``seed``, pulled towards home; through the search's shared seed-free results when it has them."""
    ik = task.ik_arm_only if solver == "arm_only" else task.ik
    if data.seed_free is not None:
        return data.seed_free.ik(solver, ik, targets, seed, rng, task.home)
    return ik.solve(targets, seed, rng, rest_q=task.home).q


def stable_posture(task: Task, data: SearchData, q: np.ndarray, sides: Sequence[Side],
                   T_obj: np.ndarray | None) -> np.ndarray | None:
    """The posture nearest ``q`` that keeps the TCPs of ``sides`` where ``q`` has them and the CoM
    margin of holding the object at ``T_obj`` (None: nothing held) at the planning threshold, moving
    the waist and the arms of ``sides``; None when there is none, or when the task is unconstrained or
    stable postures are off (:mod:`planner.motion.stable_posture`)."""
    if not (task.constrained and task.settings.stable_postures):
        return None
    data.counters["stable_postures"] += 1
    held = T_obj is not None and task.obj.mass_kg > 0.0
    problem = PostureProblem(task.robot, task.stance.base_pose, task.stance.polygon,
                             task.obj.mass_kg if held else 0.0,
                             T_obj[:3, :3] @ task.obj.com_local + T_obj[:3, 3] if held else None,
                             data=data.posture_data)
    hands = {task.robot.spec.arms[s].tcp: task.tcp(q, s) for s in sides}
    columns = np.unique(np.concatenate([task.active[s] for s in sides]))
    threshold = task.evaluator.threshold_m + task.settings.stable_posture_slack_m

    def solve() -> np.ndarray | None:
        return nearest_stable_posture(problem, q, columns, hands, threshold)

    if data.seed_free is None:
        out = solve()
    else:
        out = data.seed_free.posture((tuple(sides), threshold, *array_key(q, T_obj)), solve)
    if out is not None:
        data.counters["stable_postures_found"] += 1
    return out
