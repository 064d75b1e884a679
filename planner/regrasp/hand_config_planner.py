"""The CoM-constrained regrasp planner: the paper's planner, one hand configuration at a time.

Pipeline (one task = one scenario and one hand configuration):

1. **Task set-up** (:class:`Task`): robot, stance, object, grasps per hand (cached on
   disk), placements (start, goal and a few intermediate spots), the collision world, IK
   solvers and the stability evaluator; immutable. What the search learns (node validations,
   probes, handover poses, counters) goes into its :class:`SearchData`.
2. **Graph** (:mod:`planner.regrasp.graph`): abstract nodes after cheap checks.
3. **Lazy validation**: a node's key poses (pre-grasp, grasp, lift; at a handover the
   exchange) must be IK-feasible, collision-free and stable (margin >= threshold);
   an edge's motion comes from T-RRT (:mod:`planner.motion.trrt`), is shortcut, and is timed
   within the velocity/acceleration limits with the ZMP kept inside the polygon
   (:mod:`planner.motion.timing`). What fails is removed and the search runs again.
4. **Assembly** (:mod:`planner.regrasp.plan_assembly`): the timed pieces become the plan.

With ``threshold_m == 0`` this is the unconstrained planner: no margin constraint and
no margin cost (the paper's 0 mm comparison).
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from itertools import islice
from typing import Callable

import numpy as np

from planner.errors import Canceled
from planner.forking import helper_may_fork
from planner.grasping.grasps import Grasp
from planner.regrasp.failure_cause import FailureCause
from planner.regrasp.fork_share import share_with_child
from planner.regrasp.graph import (
    GraphSpec,
    HandoverNode,
    PlacementNode,
    RegraspGraph,
    SearchResult,
    Validation,
)
from planner.regrasp.motions import MotionValidator
from planner.regrasp.node_validation import validate_handover, validate_placement
from planner.regrasp.path_assembly import assemble_pieces
from planner.regrasp.probes import probe_givers, probe_grasps
from planner.regrasp.results import (
    HandoverPoses,
    HopResult,
    KeyPoses,
    PlannerResult,
)
from planner.regrasp.settings import HANDS_OF, Side
from planner.regrasp.search_data import SearchData
from planner.regrasp.task import Task
from planner.termination import Termination


class HandConfigPlanner:
    """Plans one hand configuration of a task: graph, lazy validation, motions."""

    def __init__(self, task: Task, hands: str, termination: Termination | None = None, *,
                 data: SearchData | None = None):
        """``termination`` (default: the scenario's ``limits``) caps each search's iterations; its deadline
        (the user's budget, none by default) and cancel cover the whole planner, motions and smoothing included.
        ``data``: the search's scratch, shared by the hand configurations of one plan or survey (a fresh one
        when not given)."""
        if hands not in HANDS_OF:
            raise ValueError(f"unknown hands {hands!r}; valid: {', '.join(HANDS_OF)}")
        self.task = task
        self.data = SearchData(task) if data is None else data
        self.hands = hands
        self.start_hand, self.goal_hand = HANDS_OF[hands]
        self.keyposes: dict[PlacementNode, KeyPoses] = {}
        self.handovers: dict[HandoverNode, HandoverPoses] = {}
        #: The motions of this configuration's hops (shares keyposes and handovers with this planner).
        self.termination = termination or Termination.of_limits(task.scenario.limits)
        self.motions = MotionValidator(task, self.data, self.keyposes, self.handovers, self.termination)
        self._validated: dict = {}
        # Why start and goal nodes failed, to tell "the start is out of reach" from "no path".
        self.start_failures: Counter = Counter()
        self.goal_failures: Counter = Counter()
        self.start_ok = False
        self.goal_ok = False
        #: "start"/"goal" -> why no node there survived the cheap filters (set by graph_spec)
        self.end_problems: dict[str, str] = {}
        self.screen_failures: Counter = Counter()
        self._edges: dict = {}
        self.stage_s: dict[str, float] = {}
        #: Why the forked helper of :meth:`_prefetch_hops` failed, if it did (its hops are then planned here).
        self.helper_errors: list[str] = []
        self.hops_by_helper = 0
        self._dropped: set = set()  # nodes removed before a search, their failure known (_drop_known_failures)
        self.direct_handover_nodes = 0  # handover nodes added by with_direct_handovers


    # -- graph construction ---------------------------------------------------------------------
    def cheap_ok(self, side: Side, T_obj: np.ndarray, grasp: Grasp) -> bool:
        """Cheap filters before IK: the hand does not come from below the table top, and is in reach."""
        T_tcp = T_obj @ grasp.T_obj_tcp
        approach = T_tcp[:3, 2]
        if approach[2] > 0.3:  # approaching upwards: the palm would be under the object
            return False
        d = T_tcp[:3, 3] - self.task.shoulder[side]
        dist = float(np.linalg.norm(d))
        if dist > self.task.reach[side]:
            return False
        # The palm faces away from the shoulder: an approach pointing back at the robot needs a contorted wrist.
        return float(approach @ d) > -0.3 * dist

    def _unreachable_reason(self, end: str, T_obj: np.ndarray, side: Side) -> str:
        """Why no grasp of the object at an end pose passed the cheap filters, in words."""
        t = self.task
        grasps = t.grasps[side]
        if not grasps:
            return f"the {side} hand has no grasp of the object"
        dist = min(float(np.linalg.norm((T_obj @ g.T_obj_tcp)[:3, 3] - t.shoulder[side])) for g in grasps)
        if dist > t.reach[side]:
            return (f"the {end} pose is out of reach of the {side} hand: its nearest grasp is {dist:.2f} m from "
                    f"the shoulder, the arm and waist reach {t.reach[side]:.2f} m")
        return (f"the {end} pose cannot be grasped by the {side} hand: every grasp there approaches from below "
                f"or points back at the robot")

    def graph_spec(self) -> GraphSpec:
        t = self.task
        # A fixed order (a set's order of strings changes with each process's hash seed, and with it
        # the node order, the tie-break ranks and so the reported cost).
        sides: list[Side] = sorted({self.start_hand, self.goal_hand})
        nodes: list[PlacementNode] = []
        for p, T in enumerate(t.placements):
            for side in sides:
                for g, grasp in enumerate(t.grasps[side]):
                    if self.cheap_ok(side, T, grasp):
                        nodes.append(PlacementNode(p, g, side))
        for end, pid, hand in (("start", t.start_id, self.start_hand), ("goal", t.goal_id, self.goal_hand)):
            if not any(n.placement == pid and n.hand == hand for n in nodes):
                self.end_problems[end] = self._unreachable_reason(end, t.placements[pid], hand)
        handovers: list[HandoverNode] = []
        if self.start_hand != self.goal_hand:
            giver = self.start_hand
            for f, hp in enumerate(self.data.handover_poses(t)):
                for r, l in hp.pairs:
                    gi, ti = (int(r), int(l)) if giver == "right" else (int(l), int(r))
                    handovers.append(HandoverNode(f, gi, ti, giver))
        positions = {p: tuple(T[:3, 3]) for p, T in enumerate(t.placements)}
        return GraphSpec(start=t.start_id, goal=t.goal_id, positions=positions, placement_nodes=nodes,
                         handover_nodes=handovers, start_hand=self.start_hand, goal_hand=self.goal_hand)

    # -- node validation ----------------------------------------------------------------------------
    def validate_node(self, node) -> Validation:
        """Validate a node once (cached across searches, e.g. for the K best solutions). A validation's long
        step (a batch probe) polls the cancel request and raises :class:`Canceled`, caching nothing; the deadline
        is the search's to check between nodes (it ends the search ``TIMEOUT``)."""
        if node in self._validated:
            return self._validated[node]
        t = self.task
        v = self.data.node_cache.get(node)
        if v is None:
            rng = np.random.default_rng(t.node_seed(node))
            v = (validate_placement(t, self.data, node, rng, self.termination.canceled) if isinstance(node, PlacementNode)
                 else validate_handover(t, self.data, node, rng))
            self.data.node_cache[node] = v  # shared with the other hand configurations of this task
        if v.ok:
            if isinstance(node, PlacementNode):
                self.keyposes[node] = v.payload
            else:  # this planner plans and times the handover's motions into its own copy of the pieces
                self.handovers[node] = dataclasses.replace(
                    v.payload, pieces=[dataclasses.replace(p) for p in v.payload.pieces])
        if isinstance(node, PlacementNode):
            for pid, hand, counter, flag in ((t.start_id, self.start_hand, self.start_failures, "start_ok"),
                                             (t.goal_id, self.goal_hand, self.goal_failures, "goal_ok")):
                if node.placement == pid and node.hand == hand:
                    if v.ok:
                        setattr(self, flag, True)
                    else:
                        counter[v.cause or FailureCause.IK] += 1
        self._validated[node] = v
        return v

    # -- search and assembly ----------------------------------------------------------------------------
    def plan(self, *, on_iteration: Callable[[int, dict], None] | None = None, solutions: int = 1) -> PlannerResult:
        """The best plan of this hand configuration, and up to ``solutions - 1`` next-best ones.

        Where the best path of a handover configuration puts the object down on a table before it hands over,
        the search runs again with the direct handover nodes added (:meth:`with_direct_handovers`), and the
        cheaper result is kept: those nodes are added only then, as more nodes of equal estimated cost can lead
        the lazy search to a valid path of a higher true cost first.

        The planner's termination caps each search's iterations; its deadline covers the whole call (a
        search past it ends ``TIMEOUT``); a cancel, or the deadline inside a motion, raises :class:`Canceled`.
        """
        t0 = time.perf_counter()
        spec = self.graph_spec()
        if self.end_problems:  # an end no hand pose can reach: no search can succeed
            end = "start" if "start" in self.end_problems else "goal"
            return PlannerResult("infeasible", self.hands, failure_code=f"{end.upper()}_INVALID", message=self.end_problems[end],
                                 failures={FailureCause.IK: len(self.end_problems)}, stats={"time_s": time.perf_counter() - t0})
        spec = self.screen(spec)
        t_search = time.perf_counter()
        found, res, failures, iterations = self._search(spec, solutions, on_iteration)
        if found and self._regrasps_before_handover(found[0].path):
            direct = self.with_direct_handovers(spec)
            if direct is not spec:  # nodes were added
                found2, res2, failures2, iterations2 = self._search(direct, solutions, on_iteration)
                failures.update(failures2)
                iterations += iterations2
                if found2 and found2[0].cost < found[0].cost:
                    found, res = found2, res2
        failures.update(self.screen_failures)  # the screening's and the known ones dropped before each search
        stage = dict(self.stage_s)
        stage["search_s"] = max(time.perf_counter() - t_search - sum(stage.values()), 0.0)
        stats = {"graph_nodes": res.graph_nodes if res else 0, "graph_edges": res.graph_edges if res else 0,
                 "search_iterations": iterations, "nodes_validated": len(self._validated) - self.dropped_known,
                 "nodes_dropped_known": self.dropped_known, "edges_validated": len(self._edges),
                 "direct_handover_nodes": self.direct_handover_nodes,
                 "hops_by_helper": self.hops_by_helper, "stage_s": stage, "time_s": time.perf_counter() - t0}
        if self.helper_errors:
            stats["helper_errors"] = list(self.helper_errors)
        if not found:
            return PlannerResult("infeasible", self.hands, failure_code=res.code if res else "NO_PATH",
                                 message=res.message if res else "", failures=dict(failures), stats=stats)
        t_asm = time.perf_counter()
        best = found[0]
        out = PlannerResult("solved", self.hands, pieces=assemble_pieces(best, self.motions), cost=best.cost,
                            failures=dict(failures), stats=stats,
                            others=[(r.cost, assemble_pieces(r, self.motions)) for r in found[1:]])
        stats["stage_s"]["assembly_s"] = time.perf_counter() - t_asm
        return out

    @property
    def dropped_known(self) -> int:
        """Nodes removed before a search, their failure already known (:meth:`_drop_known_failures`)."""
        return len(self._dropped)

    def _search(self, spec: GraphSpec, solutions: int, on_iteration: Callable[[int, dict], None] | None
                ) -> tuple[list[SearchResult], SearchResult | None, Counter, int]:
        """Up to ``solutions`` best paths of the graph of ``spec``: (found, the last search's result, the searches'
        failures, iterations)."""
        termination = self.termination
        weights = self.task.settings.weights
        if not self.task.constrained:  # the unconstrained planner: no margin cost either
            weights = dataclasses.replace(weights, margin=0.0)
        graph = RegraspGraph(spec, weights)
        self.prepare_search(graph)
        found: list[SearchResult] = []
        res: SearchResult | None = None
        failures: Counter = Counter()
        iterations = 0
        while len(found) < solutions:
            if found and termination.past_deadline():
                break
            res = graph.search(
                self._timed_node, self._timed_edge, termination, on_iteration=(lambda i, f: on_iteration(i, dict(f))) if on_iteration else None,
                banned_paths=[tuple(r.path) for r in found],
                prefetch_edges=self._prefetch_hops if self._may_share_hops() else None,
            )
            failures.update(res.failures)
            iterations += res.iterations
            if res.status != "solved":
                break
            found.append(res)
        return found, res, failures, iterations

    def _regrasps_before_handover(self, path: list) -> bool:
        """Whether a handover path puts the object down on the way (more placement nodes than its start and goal):
        the path :meth:`with_direct_handovers` looks for a direct handover in place of."""
        if self.start_hand == self.goal_hand:
            return False
        return sum(isinstance(n, PlacementNode) for n in path) > 2

    def _timed_node(self, node) -> Validation:
        t0 = time.perf_counter()
        try:
            return self.validate_node(node)
        finally:
            self.stage_s["nodes_s"] = self.stage_s.get("nodes_s", 0.0) + time.perf_counter() - t0

    def _may_share_hops(self) -> bool:
        return helper_may_fork(self.task.settings.parallel_motions)

    def _prefetch_hops(self, hops: list[tuple]) -> None:
        """Plan a candidate path's motions in this process and a forked helper at once
        (:func:`planner.regrasp.fork_share.share_with_child`), longest first so that neither process is left
        with a long one at the end: a hop into a handover whose own motions are not planned yet (it
        plans them too: two T-RRT motions, most of a dual-arm path's motion time), then the
        transits (T-RRT around the table), then the rest. Each hop draws from its own generator, so
        the verdicts are those the search would get one by one; a hop after a failing one is planned
        for nothing, and kept for later paths."""

        def plans_handover(hop: tuple) -> bool:
            b = hop[1]
            return isinstance(b, HandoverNode) and not self.handovers[b].motions_planned

        todo = sorted((h for h in hops if h not in self._edges), key=lambda h: (not plans_handover(h), h[2] != "transit"))
        if len(todo) < 2:
            return
        t0 = time.perf_counter()
        results, error = share_with_child(todo, self._hop_work, self.termination.should_stop)
        for k, res in results.items():
            b = todo[k][1]
            if res.handover is not None and not self.handovers[b].motions_planned:
                self.handovers[b] = res.handover
            self.data.counters.update(res.counts)
            self.hops_by_helper += res.by_helper
            self._edges[todo[k]] = res.validation
        if error is not None:
            self.helper_errors.append(error.strip().splitlines()[-1])
        self.stage_s["motions_s"] = self.stage_s.get("motions_s", 0.0) + time.perf_counter() - t0

    def _hop_work(self, hop: tuple, in_child: bool) -> HopResult:
        """One hop's validation; from the helper also what it changed that the parent needs: the
        handover's planned motions and the check counters."""
        a, b, kind = hop
        if not in_child:
            return HopResult(self.motions.validate_hop(a, b, kind))
        before = Counter(self.data.counters)
        v = self.motions.validate_hop(a, b, kind)
        hp = self.handovers.get(b) if isinstance(b, HandoverNode) else None
        return HopResult(v, hp if hp is not None and hp.motions_planned else None,
                          Counter(self.data.counters) - before, True)

    def _timed_edge(self, a, b, kind: str) -> Validation:
        """Edge validation, cached across searches (the K best solutions share their motions)."""
        key = (a, b, kind)
        if key not in self._edges:
            t0 = time.perf_counter()
            self._edges[key] = self.motions.validate_hop(a, b, kind)
            self.stage_s["motions_s"] = self.stage_s.get("motions_s", 0.0) + time.perf_counter() - t0
        return self._edges[key]

    def screen(self, spec: GraphSpec, want: int | None = None) -> GraphSpec:
        """Validate start and goal nodes up front, in grasp order (closest to the object's CoM first),
        until a few are valid.

        Most failures happen where the object rests at the start and goal; screening them in one
        pass spares a graph search per failed node. Nodes found invalid leave the spec.
        """
        t = self.task
        bad: set = set()
        for pid, hand in ((t.start_id, self.start_hand), (t.goal_id, self.goal_hand)):
            cands = [n for n in spec.placement_nodes if n.placement == pid and n.hand == hand]
            cands.sort(key=lambda n: n.grasp)  # grasps come sorted by their distance to the CoM
            found = 0
            for n in cands:
                if found >= (want or t.settings.screen_valid):
                    break
                if self.termination.should_stop():
                    raise Canceled()
                v = self.validate_node(n)
                if v.ok:
                    found += 1
                else:
                    bad.add(n)
                    self.screen_failures[v.cause or FailureCause.IK] += 1
        return dataclasses.replace(spec, placement_nodes=[n for n in spec.placement_nodes if n not in bad])

    def with_direct_handovers(self, spec: GraphSpec) -> GraphSpec:
        """Add handover nodes that join a start node to a goal node directly (after :meth:`screen`): at each
        handover pose up to ``handover_direct_pairs_per_pose`` usable pairs of a giver grasp still among the start
        nodes and a taker grasp still among the goal nodes, those whose grasps come first in the screening's order
        (found valid, then by grasp id, closest to the CoM first) first.

        The pairs kept per pose are spread evenly over all of them, blind to the task; a plan that hands over
        without a table regrasp needs the giver to hold the object as it picked it up and the taker as it will
        put it down, and such a pair is rarely among the few kept. The nodes are validated lazily like the
        others; a single-arm configuration gets none. :attr:`direct_handover_nodes` counts them.
        """
        keep = self.task.settings.handover_direct_pairs_per_pose
        if self.start_hand == self.goal_hand or not spec.handover_nodes or not keep:
            return spec
        t = self.task

        def ranks(pid: int, hand: Side) -> np.ndarray:
            """Each grasp id's rank among the nodes left at an end (-1: none), valid ones first."""
            alive = sorted((not (n in self._validated and self._validated[n].ok), n.grasp)
                           for n in spec.placement_nodes if n.placement == pid and n.hand == hand)
            out = np.full(len(t.grasps[hand]), -1)
            out[[g for _, g in alive]] = np.arange(len(alive))
            return out

        giver = self.start_hand
        give_rank, take_rank = ranks(t.start_id, giver), ranks(t.goal_id, self.goal_hand)
        g_col, t_col = (0, 1) if giver == "right" else (1, 0)
        have = set(spec.handover_nodes)
        added: list[HandoverNode] = []
        for f, hp in enumerate(self.data.handover_poses(t)):
            pairs = hp.every_pair
            rg, rt = give_rank[pairs[:, g_col]], take_rank[pairs[:, t_col]]
            usable = np.flatnonzero((rg >= 0) & (rt >= 0))
            order = usable[np.lexsort((rg[usable] + rt[usable], np.maximum(rg[usable], rt[usable])))]
            nodes = (HandoverNode(f, int(pairs[k, g_col]), int(pairs[k, t_col]), giver) for k in order)
            added.extend(islice((n for n in nodes if n not in have), keep))  # the first few, not all of them
        self.direct_handover_nodes = len(added)
        return dataclasses.replace(spec, handover_nodes=[*spec.handover_nodes, *added]) if added else spec

    def prepare_search(self, graph: RegraspGraph) -> None:
        """Before the first search: probe and weigh the nodes, then remove those whose failure that made known."""
        self._weigh_nodes(graph)
        self._drop_known_failures(graph)

    def _weigh_nodes(self, graph: RegraspGraph) -> None:
        """Before any node is validated, weight placement nodes by the margin of holding the object at
        their grasp (:func:`planner.regrasp.probes.probe_grasps`), so the search tries stable ones first. A node whose
        probe missed gets no margin at all (the highest margin cost): it is validated only when the
        nodes that reach their grasp have run out."""
        t = self.task
        handovers = [n for n in graph.nodes() if isinstance(n, HandoverNode)]
        if handovers:
            probe_givers(t, self.data, handovers, self.termination.canceled)
        if graph.w.margin == 0.0:
            return
        nodes = [n for n in graph.nodes() if isinstance(n, PlacementNode)]
        probes = probe_grasps(t, self.data, nodes, self.termination.canceled)
        for node in nodes:
            m = probes[node].margin_m
            graph._apply_margin_cost(node, 0.0 if m is None else m)
        for node in handovers:  # the giver's state there is one of the handover's states
            giver = self.data.giver_at.get((node.pose, node.giver_grasp, node.giver))
            if giver is not None:
                graph._apply_margin_cost(node, giver[3])

    def _drop_known_failures(self, graph: RegraspGraph) -> None:
        """Remove, before the search, the nodes already known to fail: those another hand configuration
        of the task validated, the grasps whose probe found the held object unstable, the handovers whose
        giver the probe found unstable or colliding (:meth:`validate_node` returns their verdict without
        new IK). The search would remove each only when it lay on the cheapest path, one search per
        node, and a configuration with no valid handover would reach the iteration cap before it gave up.
        Counted like the screening's failures."""
        t = self.task
        for node in list(graph.nodes()):
            if not isinstance(node, (PlacementNode, HandoverNode)):  # hubs, source and sink
                continue
            v = self.data.node_cache.get(node)
            known = v is not None and not v.ok
            if isinstance(node, HandoverNode) and not known:
                giver = self.data.giver_at.get((node.pose, node.giver_grasp, node.giver))
                known = giver is not None and giver[2] is not None
            if known:
                v = self.validate_node(node)  # the cached verdict, and the start/goal bookkeeping
                if not v.ok:
                    graph.remove_node(node)
                    if node not in self._dropped:  # counted once, however many graphs drop it
                        self._dropped.add(node)
                        self.screen_failures[v.cause or FailureCause.IK] += 1

