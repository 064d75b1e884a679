"""T-RRT, the paper's energy-based planner (Jaillet, Cortes, Simeon 2008), in the joint space of the active joints.

Trees grow like RRT in the space of the waist + active arm(s); each new node then
passes the *transition test*: a move that does not raise the cost is accepted,
a move uphill is accepted with probability ``exp(-slope / (K T))`` where the
slope is the cost rise per radian. Every accepted uphill move cools the search
(``T /= exp(0.1)``); after ``max_states_failed`` rejections in a row it heats up
(``T *= exp(0.1)``). Refinement moves (towards a random sample closer than the
frontier threshold) are allowed only while they stay below ``frontier_node_ratio``
of the frontier moves, so the trees keep exploring. The cost falls as the CoM
margin grows (``cost = -margin``), so the trees hug the stable middle of the
support polygon and the paths stay close to "minimal work" paths.

Two trees grow, one from each end, each biased towards the other's root; a new
node tries a straight connection to the nearest node of the other tree. The
search is batched for speed: each round extends ``batch_size`` samples from the
trees as they stand, checks every new edge's states in one validity call, then
applies the transition tests one by one in a fixed order, so a seed gives the
same result on any machine. One :class:`~planner.termination.Termination` says when to stop:
rounds stop on its iteration cap; its deadline (the user's own time budget, none by default)
and its cancel predicate are polled every round (cancel within milliseconds).

:func:`plan_motion` returns a path between two configurations; every state on it (nodes and
the edge states at ``edge_resolution_rad``) passed the caller's validity callback (collision +
margin >= threshold). The stability survey grows the same trees (:class:`TreeSearch`) and counts
the poses it samples (:mod:`planner.survey.counting`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.compiled.nearest_kernels import nearest_node
from planner.motion.edge_checks import (
    Validity,
    all_valid,
    all_valid_coarse_to_fine,
    coarse_mask,
    split_all,
)
from planner.motion.interpolation import edge_states
from planner.termination import Termination


class TrrtSettings(BaseModel):
    """T-RRT parameters; defaults follow Jaillet et al. / OMPL where those apply."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_iterations: int = Field(2000, ge=1, description="rounds of batch_size extensions per motion (the deterministic "
                                "cap; the motion's Termination carries it)")
    batch_size: int = Field(8, ge=1, description="extensions checked together per round (planning)")
    explore_batch_size: int = Field(64, ge=1, description="extensions checked together per round (exploration)")
    step_rad: float = Field(0.3, gt=0, description="largest extension (Euclidean, active joints)")
    edge_resolution_rad: float = Field(0.02, gt=0, description="largest per-joint change between checked states")
    goal_bias: float = Field(0.05, ge=0, le=1, description="share of samples aimed at the other tree's root")
    connect_radius_rad: float = Field(1.5, gt=0, description="try a straight connection to the other tree within this distance")
    init_temperature: float = Field(100.0, gt=0)
    temp_change_factor: float = Field(math.exp(0.1), gt=1.0)
    min_temperature: float = Field(1e-9, gt=0)
    max_states_failed: int = Field(10, ge=1, description="rejections in a row before the temperature rises")
    k_constant_m: float = Field(0.01, gt=0, description="cost scale K: metres of margin per radian")
    frontier_threshold: float = Field(0.01, gt=0, description="share of the space extent below which a move refines")
    frontier_node_ratio: float = Field(0.1, ge=0, description="refinement moves allowed per frontier move")
    margin_cost: bool = Field(True, description="cost = -margin; False: flat cost (plain RRT, the unconstrained planner)")


@dataclass
class MotionResult:
    """A path of full configurations (K, n) through valid states, or the reason there is none."""

    status: Literal["solved", "iteration_cap", "timeout", "canceled", "invalid_start", "invalid_goal", "bad_input"]
    path: np.ndarray | None
    margins: np.ndarray | None
    reason: str | None
    stats: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "solved"


class _Tree:
    """Nodes in the active-joint space with parent links, costs and its own temperature."""

    def __init__(self, root: np.ndarray, root_margin: float, capacity: int = 256):
        dim = root.shape[0]
        self.nodes = np.empty((capacity, dim))
        self.parent = np.empty(capacity, dtype=int)
        self.margin = np.empty(capacity)
        self.nodes[0] = root
        self.parent[0] = -1
        self.margin[0] = root_margin
        self.size = 1
        self.temperature = 0.0
        self.failed = 0
        self.frontier = 0
        self.refine = 0

    def add(self, q: np.ndarray, parent: int, margin: float) -> int:
        if self.size == self.nodes.shape[0]:
            cap = 2 * self.size
            self.nodes = np.resize(self.nodes, (cap, self.nodes.shape[1]))
            self.parent = np.resize(self.parent, cap)
            self.margin = np.resize(self.margin, cap)
        i = self.size
        self.nodes[i] = q
        self.parent[i] = parent
        self.margin[i] = margin
        self.size += 1
        return i

    def nearest(self, q: np.ndarray) -> tuple[int, float]:
        """The nearest node (the first of equally near ones) and its distance."""
        i, d2 = nearest_node(self.nodes, self.size, q)
        return i, math.sqrt(d2)

    def branch(self, i: int) -> list[int]:
        out = []
        while i >= 0:
            out.append(i)
            i = int(self.parent[i])
        return out


class TreeSearch:
    """Bidirectional T-RRT over one pair of end configurations (one leg of a task)."""

    def __init__(
        self,
        start: np.ndarray,
        goal: np.ndarray,
        active: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        start_margin: float,
        goal_margin: float,
        settings: TrrtSettings,
    ):
        self.template = start.copy()
        self.active = active
        self.lo, self.hi = lower[active], upper[active]
        self.s = settings
        self.trees = (_Tree(start[active], start_margin), _Tree(goal[active], goal_margin))
        for t in self.trees:
            t.temperature = settings.init_temperature
        self.extent = float(np.linalg.norm(self.hi - self.lo))
        self.frontier_dist = settings.frontier_threshold * self.extent
        self.connected: tuple[int, int] | None = None
        self.batch_size = settings.batch_size
        self.turn = 0
        self.stats = dict(rounds=0, extensions=0, invalid_edges=0, transition_rejects=0, refine_rejects=0, connect_attempts=0)

    def full(self, X: np.ndarray) -> np.ndarray:
        Q = np.repeat(self.template[None], X.shape[0], axis=0)
        Q[:, self.active] = X
        return Q

    def edge_states(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return edge_states(a, b, self.s.edge_resolution_rad)

    def cost(self, margin: float) -> float:
        return -margin if self.s.margin_cost else 0.0

    def propose(self, rng: np.random.Generator) -> list[tuple[int, int, np.ndarray, float]]:
        """A round of candidate extensions: (tree index, nearest node, new point, distance to the sample)."""
        out = []
        for _ in range(self.batch_size):
            ti = self.turn
            self.turn ^= 1
            tree, other = self.trees[ti], self.trees[ti ^ 1]
            if rng.random() < self.s.goal_bias:
                target = other.nodes[0]
            else:
                target = rng.uniform(self.lo, self.hi)
            near, dist = tree.nearest(target)
            if dist < 1e-12:
                continue
            x = tree.nodes[near]
            new = target if dist <= self.s.step_rad else x + (target - x) * (self.s.step_rad / dist)
            out.append((ti, near, np.clip(new, self.lo, self.hi), dist))
        return out

    def transition(self, tree: _Tree, parent: int, new: np.ndarray, new_margin: float, sample_dist: float, rng: np.random.Generator) -> bool:
        """Frontier control and the T-RRT transition test; updates the tree's temperature."""
        s = self.s
        if sample_dist <= self.frontier_dist:
            if tree.refine > s.frontier_node_ratio * max(tree.frontier, 1):
                self.stats["refine_rejects"] += 1
                return False
        c_new, c_par = self.cost(new_margin), self.cost(float(tree.margin[parent]))
        if c_new > c_par:
            dist = float(np.linalg.norm(new - tree.nodes[parent]))
            slope = (c_new - c_par) / max(dist, 1e-12)
            p = math.exp(-slope / (s.k_constant_m * tree.temperature))
            if rng.random() > p:
                tree.failed += 1
                if tree.failed >= s.max_states_failed:
                    tree.temperature *= s.temp_change_factor
                    tree.failed = 0
                self.stats["transition_rejects"] += 1
                return False
            tree.temperature = max(tree.temperature / s.temp_change_factor, s.min_temperature)
        tree.failed = 0
        if sample_dist <= self.frontier_dist:
            tree.refine += 1
        else:
            tree.frontier += 1
        return True

    def path(self) -> np.ndarray:
        assert self.connected is not None
        a, b = self.connected
        ta, tb = self.trees
        left = ta.branch(a)[::-1]
        right = tb.branch(b)
        X = np.vstack([ta.nodes[left], tb.nodes[right]])
        return self.full(X)

    def path_margins(self) -> np.ndarray:
        a, b = self.connected
        ta, tb = self.trees
        return np.concatenate([ta.margin[ta.branch(a)[::-1]], tb.margin[tb.branch(b)]])


def _check_inputs(start: np.ndarray, goal: np.ndarray, active: np.ndarray, nq: int) -> str | None:
    if start.shape != (nq,) or goal.shape != (nq,):
        return f"start and goal must have {nq} values, got {start.shape} and {goal.shape}"
    if not (np.all(np.isfinite(start)) and np.all(np.isfinite(goal))):
        return "start and goal must be finite"
    if active.size == 0:
        return "no active joints"
    fixed = np.ones(nq, dtype=bool)
    fixed[active] = False
    diff = np.abs(start[fixed] - goal[fixed])
    if diff.size and diff.max() > 1e-9:
        j = int(np.flatnonzero(fixed)[np.argmax(diff)])
        return f"start and goal differ in joint {j}, which is not active ({diff.max():.3g} rad)"
    return None


def _run_round(search: TreeSearch, rng: np.random.Generator, check: Validity) -> list[tuple[int, int]]:
    """Exploration round: propose, check whole edges in one call, add; returns the new (tree, node) pairs.

    ``check(Q)`` returns per state (valid, margin); an edge is accepted when all
    its states are valid and its node passes the transition test.
    """
    cands = search.propose(rng)
    if not cands:
        return []
    edges = [search.edge_states(search.trees[ti].nodes[near], new) for ti, near, new, _ in cands]
    lengths = [len(e) for e in edges]
    valid, margin = check(search.full(np.vstack(edges)))
    added = []
    for (ti, near, new, dist), ok, end in zip(cands, split_all(valid, lengths), np.cumsum(lengths) - 1):
        node_margin = float(margin[end])
        search.stats["extensions"] += 1
        if not ok:
            search.stats["invalid_edges"] += 1
            continue
        tree = search.trees[ti]
        # The trees moved since the round was proposed: the parent stays the proposed nearest node.
        if not search.transition(tree, near, new, node_margin, dist, rng):
            continue
        added.append((ti, tree.add(new, near, node_margin)))
    return added


def _edges_valid(search: TreeSearch, edges: list[np.ndarray], check: Validity, lazy: bool) -> list[bool]:
    """Whether every state of each edge is valid; lazily, a coarse pass (every ``COARSE_STRIDE``-th
    state) first, then the remaining states of the edges that survived it."""
    if not edges:
        return []
    full = [search.full(e) for e in edges]
    return all_valid_coarse_to_fine(full, check) if lazy else all_valid(full, check)


def _run_round_lazy(search: TreeSearch, rng: np.random.Generator, check: Validity) -> list[tuple[int, int]]:
    """Planning round in two validity calls: first every candidate edge's coarse states (every
    ``COARSE_STRIDE``-th state and the new node), then the transition test on the nodes that
    passed, then the remaining states of the accepted edges only.

    The collision checker, the costly part of validity, thus never sees the fine states of
    an edge whose node is invalid, collides on the way, or fails the transition test.
    """
    cands = search.propose(rng)
    if not cands:
        return []
    search.stats["extensions"] += len(cands)
    edges = [search.edge_states(search.trees[ti].nodes[near], new) for ti, near, new, _ in cands]
    coarse_masks = [coarse_mask(len(e)) for e in edges]
    coarse = [e[m] for e, m in zip(edges, coarse_masks)]
    lengths = [len(c) for c in coarse]
    valid, margin = check(search.full(np.vstack(coarse)))
    accepted = []
    for i, ((ti, near, new, dist), ok, end) in enumerate(zip(cands, split_all(valid, lengths), np.cumsum(lengths) - 1)):
        node_margin = float(margin[end])
        if not ok:
            search.stats["invalid_edges"] += 1
            continue
        if search.transition(search.trees[ti], near, new, node_margin, dist, rng):
            accepted.append((i, node_margin))
    fine_ok = {i: True for i, _ in accepted}
    todo = [i for i, _ in accepted if not coarse_masks[i].all()]
    if todo:
        fine_ok.update(zip(todo, all_valid([search.full(edges[i][~coarse_masks[i]]) for i in todo], check)))
    added = []
    for i, node_margin in accepted:
        if not fine_ok[i]:
            search.stats["invalid_edges"] += 1
            continue
        ti, near, new, _ = cands[i]
        added.append((ti, search.trees[ti].add(new, near, node_margin)))
    return added


def _try_connect(search: TreeSearch, added: list[tuple[int, int]], check: Validity, lazy: bool = False) -> None:
    """Straight connections from this round's new nodes to the nearest node of the other tree."""
    tries = []
    for ti, idx in added:
        tree, other = search.trees[ti], search.trees[ti ^ 1]
        q = tree.nodes[idx]
        j, d = other.nearest(q)
        if d <= search.s.connect_radius_rad:
            tries.append((ti, idx, j, search.edge_states(q, other.nodes[j])))
    if not tries:
        return
    search.stats["connect_attempts"] += len(tries)
    for (ti, idx, j, _), ok in zip(tries, _edges_valid(search, [t[3] for t in tries], check, lazy)):
        if ok:
            search.connected = (idx, j) if ti == 0 else (j, idx)
            return


def plan_motion(
    start: np.ndarray,
    goal: np.ndarray,
    active: Sequence[int],
    validity: Validity,
    lower: np.ndarray,
    upper: np.ndarray,
    rng: np.random.Generator,
    settings: TrrtSettings | None = None,
    termination: Termination | None = None,
) -> MotionResult:
    """T-RRT path from ``start`` to ``goal`` (full wire configurations) moving only ``active`` columns.

    ``validity`` judges batches of full configurations (collision and margin >=
    threshold, supplied by the caller) and returns their margins, which drive the
    cost. Joints outside ``active`` keep the start's values (start and goal must
    agree on them). The path's consecutive waypoints are joined by straight
    segments whose states were all checked at ``edge_resolution_rad``. ``termination`` caps the
    rounds (default: ``settings.max_iterations``, no deadline, no cancel).
    """
    s = settings or TrrtSettings()
    termination = termination or Termination(s.max_iterations)
    t0 = time.perf_counter()
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    active = np.asarray(sorted(set(int(a) for a in active)), dtype=int)
    err = _check_inputs(start, goal, active, len(lower))
    if err:
        return MotionResult("bad_input", None, None, err)
    ends_ok, ends_margin = validity(np.vstack([start, goal]))
    if not ends_ok[0]:
        return MotionResult("invalid_start", None, None, f"start configuration is not valid (margin {ends_margin[0]:.4f} m)")
    if not ends_ok[1]:
        return MotionResult("invalid_goal", None, None, f"goal configuration is not valid (margin {ends_margin[1]:.4f} m)")
    search = TreeSearch(start, goal, active, np.asarray(lower, float), np.asarray(upper, float), float(ends_margin[0]), float(ends_margin[1]), s)
    n_checked = [0]

    def check(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n_checked[0] += len(Q)
        v, m = validity(Q)
        return np.asarray(v, dtype=bool), np.asarray(m, dtype=float)

    # The straight line first: many short moves need no search at all.
    _try_connect_direct(search, check, lazy=True)
    status = "iteration_cap"
    while search.connected is None:
        if termination.canceled():
            status = "canceled"
            break
        if search.stats["rounds"] >= termination.max_iterations:
            break
        if termination.past_deadline():
            status = "timeout"
            break
        search.stats["rounds"] += 1
        added = _run_round_lazy(search, rng, check)
        if added:
            _try_connect(search, added, check, lazy=True)
    stats = dict(search.stats, nodes=[t.size for t in search.trees], states_checked=n_checked[0],
                 temperature=[t.temperature for t in search.trees], time_s=time.perf_counter() - t0)
    if search.connected is None:
        reasons = {"iteration_cap": f"no path within {termination.max_iterations} rounds", "canceled": "canceled",
                   "timeout": f"{termination.budget_text()} reached after {search.stats['rounds']} rounds"}
        return MotionResult(status, None, None, reasons[status], stats)
    return MotionResult("solved", search.path(), search.path_margins(), None, stats)


def _try_connect_direct(search: TreeSearch, check: Validity, lazy: bool = False) -> None:
    ta, tb = search.trees
    states = search.edge_states(ta.nodes[0], tb.nodes[0])
    search.stats["connect_attempts"] += 1
    if _edges_valid(search, [states], check, lazy)[0]:
        search.connected = (0, 0)


# ----------------------------------------------------------------------------- exploration (survey)
