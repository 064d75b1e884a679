"""The key paths a survey row explores: the ways the planner chooses one for a hand configuration.

R belongs to the task, stance and hand configuration, not to one key path (docs/contract.md
section 4). The planner's key path for a configuration (its grasps and, for the dual-arm rows,
its handover pose) depends on its seed: each node's IK draws from a generator seeded by the
task's seed, so which nodes validate, and so the cheapest valid path, changes with it. A survey
row therefore explores a *pool* of key paths: the planner's choice for each of the key-path seeds
``1 .. pool_size`` (the same pool whatever the survey's own base seed, so two users with different
seeds estimate the same quantity). Survey seed ``base + j`` explores pool member ``j mod
pool_size``: every planner choice gets the same share of seeds (the stratification's stated
weights: a key path the planner chose for k of the pool's seeds gets k shares), and the interval,
a bootstrap over seeds, covers the spread between the key paths.

Each draw is a pure function of (task, configuration, key-path seed): the task seeded by the
key-path seed (:func:`task_for_seed`) with a fresh search scratch, searched exactly as the planner
searches for its key poses.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Callable

from planner.regrasp.graph import HandoverNode, PlacementNode
from planner.regrasp.task import Task
from planner.survey.counting import ExploreLeg

#: Key-path seeds per row: the planner's choices the survey explores (docs/survey.md, *Key paths*).
POOL_SIZE = 8


def task_for_seed(task: Task, seed: int) -> Task:
    """The same task seeded ``seed``: what the planner with that seed searches (with a fresh
    :class:`~planner.regrasp.search_data.SearchData` of its own).

    The problem (robot, stance, object, grasps, placements, collision world, ready postures) is shared;
    the seed decides every node's and hop's generator (``Task.node_seed``). The ready postures keep the
    task's own (they come from a seed-free grid of postures wherever the arm has one)."""
    if seed == task.seed:
        return task
    t = copy.copy(task)
    object.__setattr__(t, "seed", int(seed))  # a built Task is immutable; this copy is born with its own seed
    return t


def node_id(n: PlacementNode | HandoverNode) -> dict:
    """A key-path node by its ids (placement, grasp, hand; or handover pose, giver and taker grasps)."""
    if isinstance(n, PlacementNode):
        return {"placement": n.placement, "grasp": n.grasp, "hand": n.hand}
    return {"handover_pose": n.pose, "giver_grasp": n.giver_grasp, "taker_grasp": n.taker_grasp, "giver": n.giver}


@dataclass
class KeyPathDraw:
    """The planner's key path for one configuration at one key-path seed, and the legs it carries the object on
    (without their collision checks, so that a draw can cross processes)."""

    hands: str
    seed: int
    nodes: list[dict] | None
    legs: list[ExploreLeg] = field(default_factory=list)
    reason: str | None = None
    time_s: float = 0.0

    @property
    def ok(self) -> bool:
        return self.nodes is not None and bool(self.legs)

    def label(self) -> dict:
        """What a ``per_seed`` entry names: the key-path seed and its nodes by id."""
        return {"seed": self.seed, "nodes": self.nodes}


def pool_seeds(size: int = POOL_SIZE) -> list[int]:
    """The key-path seeds of every survey's pool."""
    return list(range(1, size + 1))


DrawFn = Callable[[Task, str, int], KeyPathDraw]
