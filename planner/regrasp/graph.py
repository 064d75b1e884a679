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

from collections import Counter
from dataclasses import dataclass, field
from typing import Callable, Generic, Hashable, Iterable, Literal, TypeVar

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from planner.errors import Canceled
from planner.regrasp.failure_cause import FailureCause, failures_in_words
from planner.termination import Termination

Hand = Literal["left", "right"]
SOURCE = ("source",)
SINK = ("sink",)
#: What a validation carries for its caller (the graph never looks inside).
Payload = TypeVar("Payload")


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
class Validation(Generic[Payload]):
    """The outcome of validating a node or an edge, MoveIt Task Constructor's solution: valid or not,
    the cause of a failure (ik/collision/com_margin/motion) with a comment (``detail``), the margin
    as its clearance, and what the validation produced (``payload``: key poses, a handover's
    motions, timed pieces; the graph passes it through untouched). ``remove_node`` asks the search
    to drop the edge's arriving node, not only the edge (its own motions cannot be planned)."""

    ok: bool
    cause: FailureCause | None = None
    detail: str = ""
    margin_m: float | None = None
    payload: Payload | None = None
    remove_node: bool = False


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


#: Cost per place in the spec's node order: breaks ties without outweighing real costs (<= 1e-3 for 10^4 nodes).
TIE_BREAK = 1e-7
_KINDS = ("start", "end", "transit", "transfer", "handover")
#: The kinds of motion between key poses (a path's hops; start and end edges carry none).
HOP_KINDS = _KINDS[2:]
_KIND_CODE = {k: i for i, k in enumerate(_KINDS)}


class RegraspGraph:
    """The lazily validated regrasp graph of one task and one hand configuration.

    Stored as flat edge arrays in CSR order (scipy's compiled Dijkstra runs on them in a few
    milliseconds; a dual-arm graph has ~10^5 edges, where a pure-Python Dijkstra took ~0.1 s
    per search). Removing a node or an edge sets its weight to infinity; the structure is
    never rebuilt.
    """

    def __init__(self, spec: GraphSpec, weights: GraphWeights | None = None):
        self.spec = spec
        self.w = weights or GraphWeights()
        self._build()

    # -- construction -------------------------------------------------------------------------
    def _build(self) -> None:
        s, w = self.spec, self.w
        single_arm = s.start_hand == s.goal_hand
        ids: dict[Hashable, int] = {SOURCE: 0, SINK: 1}
        nodes: list[Hashable] = [SOURCE, SINK]

        def nid(n: Hashable) -> int:
            i = ids.get(n)
            if i is None:
                i = ids[n] = len(nodes)
                nodes.append(n)
            return i

        src: list[int] = []
        dst: list[int] = []
        wt: list[float] = []
        kd: list[int] = []

        def edge(a: int, b: int, weight: float, kind: str) -> None:
            src.append(a)
            dst.append(b)
            wt.append(weight)
            kd.append(_KIND_CODE[kind])

        by_grasp_hand: dict[tuple[int, Hand], list[int]] = {}
        for n in s.placement_nodes:
            # Single-arm configurations use one hand throughout; dual-arm ones pick with the
            # start hand and place with the goal hand, changing hands only by handover.
            if single_arm and n.hand != s.start_hand:
                continue
            i = nid(n)
            by_grasp_hand.setdefault((n.grasp, n.hand), []).append(i)
            if n.placement == s.start and n.hand == s.start_hand:
                edge(0, i, 0.0, "start")
            if n.placement == s.goal and n.hand == s.goal_hand:
                edge(i, 1, 0.0, "end")
            hub = nid(Hub(n.placement, n.hand))
            edge(i, hub, w.regrasp / 2, "transit")
            edge(hub, i, w.regrasp / 2, "transit")
        for members in by_grasp_hand.values():
            for a in members:
                pa = s.positions[nodes[a].placement]
                for b in members:
                    if nodes[a].placement != nodes[b].placement:
                        edge(a, b, w.transfer + w.distance * _dist(pa, s.positions[nodes[b].placement]), "transfer")
        if not single_arm:
            for h in s.handover_nodes:
                if h.giver != s.start_hand:
                    continue
                i = nid(h)
                for a in by_grasp_hand.get((h.giver_grasp, h.giver), []):
                    edge(a, i, w.handover / 2 + w.transfer, "handover")
                for b in by_grasp_hand.get((h.taker_grasp, h.taker), []):
                    edge(i, b, w.handover / 2 + w.transfer, "handover")
        n_nodes = len(nodes)
        # Equal costs are common (every grasp of a placement costs the same before validation):
        # a tiny rank term breaks ties towards the order the spec lists nodes in (grasps come
        # sorted by distance to the object's CoM, the likeliest to be valid first).
        rank = np.zeros(n_nodes)
        for k, n in enumerate([*s.placement_nodes, *s.handover_nodes]):
            i = ids.get(n)
            if i is not None:
                rank[i] = TIE_BREAK * k
        src_a, dst_a = np.asarray(src, dtype=np.int64), np.asarray(dst, dtype=np.int64)
        # CSR order (by source, then target); a repeated (a, b) keeps its last weight.
        key = src_a * n_nodes + dst_a
        order = np.lexsort((-np.arange(key.size), key))
        keep = np.ones(order.size, dtype=bool)
        keep[1:] = key[order][1:] != key[order][:-1]
        order = order[keep]
        self._nodes = nodes
        self._ids = ids
        self._src, self._dst = src_a[order], dst_a[order]
        self._base = np.asarray(wt, dtype=float)[order] + rank[self._dst]
        self._kind = np.asarray(kd, dtype=np.int8)[order]
        self._edge_alive = np.ones(order.size, dtype=bool)
        self._node_alive = np.ones(n_nodes, dtype=bool)
        indptr = np.zeros(n_nodes + 1, dtype=np.int64)
        np.cumsum(np.bincount(self._src, minlength=n_nodes), out=indptr[1:])
        self._indptr = indptr
        self._csr = csr_matrix((self._base.copy(), self._dst.astype(np.int32), indptr.astype(np.int32)), shape=(n_nodes, n_nodes))
        by_dst = np.argsort(self._dst, kind="stable")
        in_ptr = np.zeros(n_nodes + 1, dtype=np.int64)
        np.cumsum(np.bincount(self._dst, minlength=n_nodes), out=in_ptr[1:])
        self._in_edges, self._in_ptr = by_dst, in_ptr
        self._extra = np.zeros(self._base.size)  # margin cost on top of the base weight

    # -- queries and edits ----------------------------------------------------------------------
    @property
    def size(self) -> tuple[int, int]:
        return int(self._node_alive.sum()), int(self._edge_alive.sum())

    def __contains__(self, node: Hashable) -> bool:
        i = self._ids.get(node)
        return i is not None and bool(self._node_alive[i])

    def nodes(self) -> list[Hashable]:
        """The live nodes (placement, handover, hub, source and sink)."""
        return [self._nodes[i] for i in np.flatnonzero(self._node_alive)]

    def _incoming(self, i: int) -> np.ndarray:
        return self._in_edges[self._in_ptr[i]:self._in_ptr[i + 1]]

    def _edge(self, a: Hashable, b: Hashable) -> int | None:
        ia, ib = self._ids.get(a), self._ids.get(b)
        if ia is None or ib is None:
            return None
        lo, hi = self._indptr[ia], self._indptr[ia + 1]
        k = lo + int(np.searchsorted(self._dst[lo:hi], ib))
        if k < hi and self._dst[k] == ib and self._edge_alive[k]:
            return k
        return None

    def kind(self, a: Hashable, b: Hashable) -> str:
        """The kind of the live edge a -> b (start, end, transit, transfer, handover)."""
        k = self._edge(a, b)
        if k is None:
            raise KeyError(f"no edge {a} -> {b}")
        return _KINDS[self._kind[k]]

    def weight(self, a: Hashable, b: Hashable) -> float:
        k = self._edge(a, b)
        if k is None:
            raise KeyError(f"no edge {a} -> {b}")
        return float(self._base[k] + self._extra[k])

    def remove_node(self, node: Hashable) -> None:
        i = self._ids.get(node)
        if i is None or not self._node_alive[i]:
            return
        self._node_alive[i] = False
        self._edge_alive[self._indptr[i]:self._indptr[i + 1]] = False
        self._edge_alive[self._incoming(i)] = False

    def remove_edge(self, a: Hashable, b: Hashable) -> None:
        k = self._edge(a, b)
        if k is not None:
            self._edge_alive[k] = False

    def to_networkx(self):
        """The live graph as a ``networkx.DiGraph``: edge attributes ``weight`` (the current cost,
        margin term included) and ``kind``; the super source and sink are ``SOURCE`` and ``SINK``.

        For analysis, drawing and export, and as the reference the compiled search is tested
        against (networkx's Dijkstra on this graph finds the same cost). The search itself runs on
        the flat arrays: networkx takes far longer per search (``benchmarks/bench_graph.py`` prints
        both), which a lazy search repeating it a few hundred times would turn into seconds.
        """
        import networkx as nx

        g = nx.DiGraph()
        g.add_nodes_from(self._nodes[i] for i in np.flatnonzero(self._node_alive))
        live = np.flatnonzero(self._edge_alive)
        weights = self._base[live] + self._extra[live]
        g.add_edges_from((self._nodes[a], self._nodes[b], {"weight": float(wt), "kind": _KINDS[k]})
                         for a, b, wt, k in zip(self._src[live], self._dst[live], weights, self._kind[live]))
        return g

    def shortest(self) -> tuple[list, float] | None:
        """The cheapest live path from the super source to the sink and its cost (no validation)."""
        self._csr.data[:] = np.where(self._edge_alive, self._base + self._extra, np.inf)
        dist, pred = dijkstra(self._csr, directed=True, indices=0, return_predecessors=True)
        if not np.isfinite(dist[1]):
            return None
        path = [1]
        while path[-1] != 0:
            path.append(int(pred[path[-1]]))
        return [self._nodes[i] for i in reversed(path)], float(dist[1])

    def _apply_margin_cost(self, node: Hashable, margin: float | None) -> bool:
        """Once a node's margin is known, edges into it cost more the closer it is to the edge.

        Returns whether the summed weight of the live edges into ``node`` rose.
        """
        if margin is None or self.w.margin == 0.0 or node not in self:
            return False
        extra = self.w.margin * max(0.0, 1.0 - margin / self.w.margin_ref_m)
        e = self._incoming(self._ids[node])
        live = e[self._edge_alive[e]]
        before = float((self._base[live] + self._extra[live]).sum())
        self._extra[e] = extra
        return float((self._base[live] + self._extra[live]).sum()) > before + 1e-12

    def search(
        self,
        validate_node: Callable[[Node], Validation],
        validate_edge: Callable[[Node | None, Node | None, str], Validation],
        termination: Termination,
        *,
        on_iteration: Callable[[int, Counter], None] | None = None,
        banned_paths: Iterable[tuple[Hashable, ...]] = (),
        prefetch_edges: Callable[[list[tuple[Node | None, Node | None, str]]], None] | None = None,
    ) -> SearchResult:
        """Find the cheapest fully valid path; never loops forever, never raises on infeasibility.

        ``validate_edge(a, b, kind)`` plans the motion from node a to node b (``a`` is None for
        the motion from the robot's home posture to the first node, ``b`` None for the return).
        Validations are cached, so re-searches cost only the new parts. ``prefetch_edges``, if
        given, is told a candidate path's unvalidated hops (two or more) before they are validated
        in order, to work on them at once; ``validate_edge`` must give the same verdicts either way.
        ``termination`` caps the iterations, sets the deadline (the result is then ``TIMEOUT``) and
        says when to stop (:class:`Canceled` is raised).
        """
        should_stop = termination.canceled
        max_iterations = termination.max_iterations
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
            if termination.past_deadline():
                result.code, result.message = "TIMEOUT", f"no valid path within the time limit of {termination.time_limit_s:g} s"
                break
            if on_iteration:
                on_iteration(iteration, failures)
            found = self.shortest()
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
                        weight_changed |= self._apply_margin_cost(node, v.margin_m)
                v = node_cache[node]
                if not v.ok:
                    # Stop at the first invalid node: the rest of this path may never be needed.
                    failures[v.cause or FailureCause.IK] += 1
                    self.remove_node(node)
                    bad = True
                    break
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
                hops.append((a, b, self.kind(a, b)))
                i += 1
            hops.append((path[-1], None, "transit"))
            if prefetch_edges is not None:
                todo = [h for h in hops if h not in edge_cache]
                if len(todo) > 1:
                    if should_stop():
                        raise Canceled()
                    prefetch_edges(todo)
            edge_results: list[Validation] = []
            for a, b, kind in hops:
                key = (a, b, kind)
                if key not in edge_cache:
                    if should_stop():
                        raise Canceled()
                    edge_cache[key] = validate_edge(a, b, kind)
                v = edge_cache[key]
                if not v.ok:
                    failures[v.cause or FailureCause.MOTION] += 1
                    if v.remove_node and b is not None and b in self:
                        self.remove_node(b)
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
            result.message += f"; {failures_in_words(failures, 'states removed')}"
        return result

    def _remove_hop(self, a: Node | None, b: Node | None, kind: str) -> None:
        """Remove what a failed motion used: a direct edge, or the arriving node of a transit."""
        if a is not None and b is not None and self._edge(a, b) is not None:
            self.remove_edge(a, b)
            return
        # Motions through a hub, or to/from the home posture: remove the node that is not home.
        node = b if b is not None else a
        if node is not None:
            self.remove_node(node)

    def _ban_most_expensive(self, full: list) -> None:
        u, v = max(zip(full[:-1], full[1:]), key=lambda e: self.weight(*e))
        self.remove_edge(u, v)


def _dominant_code(failures: Counter) -> str:
    cause = failures.most_common(1)[0][0]
    return FailureCause(cause).code if cause in set(FailureCause) else "NO_PATH"
