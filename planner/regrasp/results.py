"""What the regrasp planner's stages produce: key poses of a node, the motions of a handover, grasp
probes, a hop's outcome, and the planner's result with its cost, failures and alternatives."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from planner.regrasp.graph import Validation
from planner.regrasp.plan_assembly import MotionPiece


@dataclass
class KeyPoses:
    """Validated key configurations of a placement node."""

    q_pre: np.ndarray
    q_grasp_open: np.ndarray
    q_grasp: np.ndarray  # jaw closed
    q_lift: np.ndarray
    T_obj: np.ndarray  # the object where it rests
    T_obj_tcp: np.ndarray  # the actual grasp (TCP in the object frame) at q_grasp
    margin: float


@dataclass
class HandoverPoses:
    q_giver_at: np.ndarray  # giver at the handover pose, taker arm at home
    #: taker transit, approach, close, giver open, retreat, giver home; the two transits are
    #: planned (T-RRT) only once a path through this node is otherwise valid
    pieces: list[MotionPiece]
    q_after: np.ndarray  # taker holds, giver arm back home
    T_taker_obj_tcp: np.ndarray  # the taker's grasp relative to the object, as nominal
    margin: float
    motions_planned: bool = False


@dataclass
class PlannerResult:
    status: Literal["solved", "infeasible"]
    hands: str
    pieces: list[MotionPiece] = field(default_factory=list)
    cost: float = float("inf")
    min_margin_m: float | None = None
    failure_code: str | None = None
    message: str = ""
    failures: dict[str, int] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    #: The next-best solutions of this hand configuration: (cost, pieces) each, cheapest first.
    others: list[tuple[float, list[MotionPiece]]] = field(default_factory=list)


@dataclass(frozen=True)
class GraspProbe:
    """A placement node's IK solution at the grasp pose (jaw open), and the CoM margin of holding the
    object there: the arm alone first (:func:`planner.regrasp.probes.probe_grasps`), the waist helping where it missed
    (:func:`planner.regrasp.probes.probe_grasps_with_waist`, once a search reaches such a node); both None while no
    batched attempt reached (the node's own validation then solves it one by one)."""

    q: np.ndarray | None
    margin_m: float | None


@dataclass
class HopResult:
    """A hop's validation, and what planning it in the forked helper changed that this process needs."""

    validation: Validation
    handover: HandoverPoses | None = None  # the handover node's motions, planned by this hop
    counts: Counter = field(default_factory=Counter)  # the helper's check counters
    by_helper: bool = False

