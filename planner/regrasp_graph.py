"""The regrasp graph: placements x grasps x hands, searched lazily.

Nodes are *abstract* until validated: a node says "the object rests at placement
``p`` and hand ``h`` holds it with grasp ``g``" (or, at a handover pose, both
hands hold it). Building every node's IK up front is what makes public regrasp
planners slow, so here a node enters the graph after cheap checks only, and the
search validates lazily: Dijkstra finds the cheapest path, the caller's
validators expand its nodes into key poses (IK, collision, CoM margin) and its
edges into motions; whatever fails is removed and the search runs again.

Size is kept linear: a regrasp at a placement goes through a per-placement hub
(release, then grasp again) instead of a clique over every grasp pair; carrying
the object between placements with one grasp is a direct edge, of which there are
``P^2`` per grasp and hand, with ``P`` kept small (start, goal and a few spots).

Failures are counted by cause (ik, collision, com_margin, motion). The loop is
bounded by an iteration cap (the reproducible stop) and a time limit (a safety
net), and polls a cancel callback.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable, Hashable, Iterable, Literal

import networkx as nx

Hand = Literal["left", "right"]
SOURCE = ("source",)
#: A failed edge whose failure belongs to its arriving node: remove the node, not only the edge.
REMOVE_NODE = "remove-node"
SINK = ("sink",)


@dataclass(frozen=True)
class GraphWeights:
    """Edge costs. Units: a regrasp or handover counts as one, distances in metres."""

    regrasp: float = 1.0
    handover: float = 1.0
    transfer: float = 0.2
    distance: float = 1.0
    #: Weight of the CoM-margin term: cost += margin * max(0, 1 - margin / margin_ref).
    margin: float = 1.0
    margin_ref_m: float = 0.10


@dataclass(frozen=True)
class PlacementNode:
    placement: int
    grasp: int
    hand: Hand

    @property
    def kind(self) -> str:
        return "pg"


@dataclass(frozen=True)
class HandoverNode:
    pose: int
    giver_grasp: int
    taker_grasp: int
    giver: Hand

    @property
    def kind(self) -> str:
        return "ho"

    @property
    def taker(self) -> Hand:
        return "right" if self.giver == "left" else "left"


@dataclass(frozen=True)
class Hub:
    placement: int
    hand: Hand


Node = PlacementNode | HandoverNode


@dataclass
class Validation:
    """The outcome of validating a node or an edge; ``cause`` is ik/collision/com_margin/motion."""

    ok: bool
    cause: str | None = None
    detail: str = ""
    margin_m: float | None = None
    payload: object = None


@dataclass
class SearchResult:
    status: Literal["solved", "infeasible"]
    path: list[Node] = field(default_factory=list)
    cost: float = float("inf")
    edges: list[Validation] = field(default_factory=list)
    nodes: list[Validation] = field(default_factory=list)
    failures: Counter = field(default_factory=Counter)
    code: str | None = None
    message: str = ""
    iterations: int = 0
    graph_nodes: int = 0
    graph_edges: int = 0


class Canceled(Exception):
    pass


@dataclass
class GraphSpec:
    """What the graph is built from: which (placement, grasp, hand) and handover nodes exist."""

    start: int
    goal: int
    #: placement id -> (x, y, z) of the object, for distance costs
    positions: dict[int, tuple[float, float, float]]
    #: nodes that passed the cheap checks
    placement_nodes: list[PlacementNode]
    handover_nodes: list[HandoverNode] = field(default_factory=list)
    start_hand: Hand = "right"
    goal_hand: Hand = "right"


def _dist(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    return sum((x - y) ** 2 for x, y in zip(a, b)) ** 0.5


class RegraspGraph:
    """The lazily validated regrasp graph of one task and one hand configuration."""

    def __init__(self, spec: GraphSpec, weights: GraphWeights | None = None):
        self.spec = spec
        self.w = weights or GraphWeights()
        self.g = nx.DiGraph()
        self._build()

    # -- construction -------------------------------------------------------------------------
    def _build(self) -> None:
        s, w, g = self.spec, self.w, self.g
        single_arm = s.start_hand == s.goal_hand
        by_grasp_hand: dict[tuple[int, Hand], list[PlacementNode]] = {}
        for n in s.placement_nodes:
            # Single-arm configurations use one hand throughout; dual-arm ones pick with the
            # start hand and place with the goal hand, changing hands only by handover.
            if single_arm and n.hand != s.start_hand:
                continue
            g.add_node(n)
            by_grasp_hand.setdefault((n.grasp, n.hand), []).append(n)
            if n.placement == s.start and n.hand == s.start_hand:
                g.add_edge(SOURCE, n, weight=0.0, kind="start")
            if n.placement == s.goal and n.hand == s.goal_hand:
                g.add_edge(n, SINK, weight=0.0, kind="end")
            hub = Hub(n.placement, n.hand)
            g.add_edge(n, hub, weight=w.regrasp / 2, kind="transit")
            g.add_edge(hub, n, weight=w.regrasp / 2, kind="transit")
        for nodes in by_grasp_hand.values():
            for a in nodes:
                for b in nodes:
                    if a.placement != b.placement:
                        cost = w.transfer + w.distance * _dist(s.positions[a.placement], s.positions[b.placement])
                        g.add_edge(a, b, weight=cost, kind="transfer")
        if not single_arm:
            for h in s.handover_nodes:
                if h.giver != s.start_hand:
                    continue
                g.add_node(h)
                for a in by_grasp_hand.get((h.giver_grasp, h.giver), []):
                    g.add_edge(a, h, weight=w.handover / 2 + w.transfer, kind="handover")
                for b in by_grasp_hand.get((h.taker_grasp, h.taker), []):
                    g.add_edge(h, b, weight=w.handover / 2 + w.transfer, kind="handover")

    @property
    def size(self) -> tuple[int, int]:
        return self.g.number_of_nodes(), self.g.number_of_edges()

    # -- lazy search --------------------------------------------------------------------------
    def _shortest(self) -> tuple[list, float] | None:
        try:
            length, path = nx.single_source_dijkstra(self.g, SOURCE, SINK, weight="weight")
        except (nx.NetworkXNoPath, nx.NodeNotFound):
            return None
        return path, float(length)

    def _apply_margin_cost(self, node: Node, margin: float | None) -> None:
        """Once a node's margin is known, edges into it cost more the closer it is to the edge."""
        if margin is None or self.w.margin == 0.0:
            return
        extra = self.w.margin * max(0.0, 1.0 - margin / self.w.margin_ref_m)
        for u in self.g.predecessors(node):
            data = self.g.edges[u, node]
            data.setdefault("base_weight", data["weight"])
            data["weight"] = data["base_weight"] + extra

    def search(
        self,
        validate_node: Callable[[Node], Validation],
        validate_edge: Callable[[Node | None, Node | None, str], Validation],
        *,
        max_iterations: int,
        time_limit_s: float,
        should_stop: Callable[[], bool] = lambda: False,
        on_iteration: Callable[[int, Counter], None] | None = None,
        banned_paths: Iterable[tuple[Hashable, ...]] = (),
    ) -> SearchResult:
        """Find the cheapest fully valid path; never loops forever, never raises on infeasibility.

        ``validate_edge(a, b, kind)`` plans the motion from node a to node b (``a`` is None for
        the motion from the robot's home posture to the first node, ``b`` None for the return).
        Validations are cached, so re-searches cost only the new parts.
        """
        started = time.monotonic()
        failures: Counter = Counter()
        node_cache: dict[Node, Validation] = {}
        edge_cache: dict[tuple, Validation] = {}
        banned = {tuple(p) for p in banned_paths}
        result = SearchResult(status="infeasible")
        n0, e0 = self.size
        result.graph_nodes, result.graph_edges = n0, e0
        for iteration in range(1, max_iterations + 1):
            result.iterations = iteration
            if should_stop():
                raise Canceled()
            if time.monotonic() - started > time_limit_s:
                result.code, result.message = "TIMEOUT", f"no valid path within the time limit of {time_limit_s:g} s"
                break
            if on_iteration:
                on_iteration(iteration, failures)
            found = self._shortest()
            if found is None:
                result.code = "NO_PATH"
                result.message = "no path connects the start and goal placements through valid states"
                break
            full, cost = found
            path = [n for n in full if isinstance(n, (PlacementNode, HandoverNode))]
            # 1. Nodes: key poses (IK, collision, CoM margin).
            bad = False
            weight_changed = False
            for node in path:
                if node not in node_cache:
                    if should_stop():
                        raise Canceled()
                    node_cache[node] = validate_node(node)
                    v = node_cache[node]
                    if v.ok:
                        before = sum(self.g.edges[u, node]["weight"] for u in self.g.predecessors(node))
                        self._apply_margin_cost(node, v.margin_m)
                        after = sum(self.g.edges[u, node]["weight"] for u in self.g.predecessors(node))
                        weight_changed |= after > before + 1e-12
                v = node_cache[node]
                if not v.ok:
                    failures[v.cause or "ik"] += 1
                    self.g.remove_node(node)
                    bad = True
            if bad or weight_changed:
                continue
            if tuple(path) in banned:
                self._ban_most_expensive(full)
                continue
            # 2. Edges: motions between consecutive key poses, home first and last.
            hops: list[tuple[Node | None, Node | None, str]] = [(None, path[0], "transit")]
            seq = full[1:-1]
            i = 0
            while i < len(seq) - 1:
                a, b = seq[i], seq[i + 1]
                if isinstance(b, Hub):
                    c = seq[i + 2]
                    hops.append((a, c, "transit"))
                    i += 2
                    continue
                hops.append((a, b, self.g.edges[a, b]["kind"]))
                i += 1
            hops.append((path[-1], None, "transit"))
            edge_results: list[Validation] = []
            for a, b, kind in hops:
                key = (a, b, kind)
                if key not in edge_cache:
                    if should_stop():
                        raise Canceled()
                    edge_cache[key] = validate_edge(a, b, kind)
                v = edge_cache[key]
                if not v.ok:
                    failures[v.cause or "motion"] += 1
                    if v.payload == REMOVE_NODE and b is not None and b in self.g:
                        self.g.remove_node(b)
                    else:
                        self._remove_hop(a, b, kind)
                    bad = True
                    break
                edge_results.append(v)
            if bad:
                continue
            result.status = "solved"
            result.path = path
            result.cost = cost
            result.nodes = [node_cache[n] for n in path]
            result.edges = edge_results
            result.code, result.message = None, ""
            break
        else:
            result.code = "NO_PATH" if not failures else _dominant_code(failures)
            result.message = f"no valid path after {max_iterations} search iterations (the iteration cap)"
        result.failures = failures
        if result.status != "solved" and result.code in ("NO_PATH",) and failures:
            result.code = _dominant_code(failures)
            result.message += f"; removed states by cause: {dict(failures)}"
        return result

    def _remove_hop(self, a: Node | None, b: Node | None, kind: str) -> None:
        """Remove what a failed motion used: a direct edge, or the arriving node of a transit."""
        if a is not None and b is not None and self.g.has_edge(a, b):
            self.g.remove_edge(a, b)
            return
        # Motions through a hub, or to/from the home posture: remove the node that is not home.
        node = b if b is not None else a
        if node is not None and node in self.g:
            self.g.remove_node(node)

    def _ban_most_expensive(self, full: list) -> None:
        u, v = max(zip(full[:-1], full[1:]), key=lambda e: self.g.edges[e]["weight"])
        self.g.remove_edge(u, v)


def _dominant_code(failures: Counter) -> str:
    cause = failures.most_common(1)[0][0]
    return {"ik": "IK_FAIL", "collision": "COLLISION", "com_margin": "COM_MARGIN", "motion": "MOTION"}.get(cause, "NO_PATH")
