"""The lazy regrasp graph search with mock validators (no robot needed)."""

from __future__ import annotations

import pytest

from planner.regrasp.graph import (
    Canceled,
    GraphSpec,
    GraphWeights,
    HandoverNode,
    PlacementNode,
    RegraspGraph,
    Validation,
)
from planner.termination import Termination


def spec(hands=("right", "right"), grasps=(0, 1, 2), placements=(0, 1, 2), handovers=()):
    positions = {p: (0.4, -0.3 + 0.3 * p, 0.8) for p in placements}
    nodes = [PlacementNode(p, g, h) for p in placements for g in grasps for h in ("left", "right")]
    return GraphSpec(start=0, goal=2, positions=positions, placement_nodes=nodes,
                     handover_nodes=list(handovers), start_hand=hands[0], goal_hand=hands[1])


def ok_edge(a, b, kind):
    return Validation(True)


def test_direct_transfer_is_the_cheapest_path():
    g = RegraspGraph(spec())
    res = g.search(lambda n: Validation(True, margin_m=0.2), ok_edge, Termination(50, 5))
    assert res.status == "solved"
    assert [n.placement for n in res.path] == [0, 2]
    assert res.path[0].grasp == res.path[1].grasp and all(n.hand == "right" for n in res.path)


def test_failing_nodes_are_removed_and_counted_by_cause():
    # Grasp 0 is IK-infeasible at the goal; grasp 1 unstable at the goal: a regrasp is needed.
    def node(n):
        if n.placement == 2 and n.grasp == 0:
            return Validation(False, "ik")
        if n.placement == 2 and n.grasp == 1:
            return Validation(False, "com_margin")
        if n.placement == 0 and n.grasp == 2:
            return Validation(False, "collision")
        return Validation(True, margin_m=0.2)

    res = RegraspGraph(spec()).search(node, ok_edge, Termination(100, 5))
    assert res.status == "solved"
    assert res.path[-1].placement == 2 and res.path[-1].grasp == 2
    assert res.failures["ik"] >= 1 and res.failures["com_margin"] >= 1
    # The path changes grasp somewhere (a regrasp): grasp 0 or 1 at the start, grasp 2 at the goal.
    assert res.path[0].grasp in (0, 1)


def test_motion_failure_removes_the_edge_and_replans():
    failed: set[int] = set()  # the grasp of the first transfer tried cannot carry the object anywhere

    def edge(a, b, kind):
        if kind == "transfer" and (not failed or a.grasp in failed):
            failed.add(a.grasp)
            return Validation(False, "motion")
        return Validation(True)

    res = RegraspGraph(spec()).search(lambda n: Validation(True, margin_m=0.2), edge, Termination(100, 5))
    assert res.status == "solved" and res.failures["motion"] >= 1
    assert all(n.grasp not in failed for n in res.path)


def test_margin_cost_prefers_the_more_stable_node():
    margins = {0: 0.01, 1: 0.09, 2: 0.05}
    res = RegraspGraph(spec(), GraphWeights(margin=5.0)).search(
        lambda n: Validation(True, margin_m=margins[n.grasp]), ok_edge, Termination(100, 5))
    assert res.path[0].grasp == 1


def test_infeasible_returns_reasons_not_an_exception():
    res = RegraspGraph(spec()).search(lambda n: Validation(False, "com_margin"), ok_edge, Termination(500, 5))
    assert res.status == "infeasible"
    assert res.code == "COM_MARGIN" and res.failures["com_margin"] > 0


def test_iteration_cap_bounds_the_search():
    res = RegraspGraph(spec()).search(lambda n: Validation(False, "ik"), ok_edge, Termination(3, 5))
    assert res.status == "infeasible" and res.iterations == 3


def test_dual_arm_goes_through_a_handover():
    handovers = [HandoverNode(0, gr, gl, "right") for gr in (0, 1) for gl in (1, 2)]
    res = RegraspGraph(spec(hands=("right", "left"), handovers=handovers)).search(
        lambda n: Validation(True, margin_m=0.2), ok_edge, Termination(50, 5))
    assert res.status == "solved"
    kinds = [n.kind for n in res.path]
    assert kinds == ["pg", "ho", "pg"]
    assert res.path[0].hand == "right" and res.path[-1].hand == "left"
    assert res.path[0].grasp == res.path[1].giver_grasp and res.path[2].grasp == res.path[1].taker_grasp


def test_single_arm_never_uses_the_other_hand():
    res = RegraspGraph(spec(hands=("left", "left"))).search(lambda n: Validation(True, margin_m=0.2), ok_edge,
                                                          Termination(50, 5))
    assert all(n.hand == "left" for n in res.path)


def test_cancel_raises():
    with pytest.raises(Canceled):
        RegraspGraph(spec()).search(lambda n: Validation(True), ok_edge, Termination(50, 5, lambda: True))


def test_graph_stays_linear_in_grasps():
    """A regrasp goes through a hub: edges grow linearly with grasps at one placement, not quadratically."""
    small = RegraspGraph(spec(grasps=tuple(range(10)), placements=(0, 2))).size[1]
    large = RegraspGraph(spec(grasps=tuple(range(100)), placements=(0, 2))).size[1]
    assert large < 12 * small


def test_removed_nodes_and_edges_leave_the_search():
    g = RegraspGraph(spec())
    nodes, edges = g.size
    victim = PlacementNode(2, 0, "right")
    assert victim in g
    g.remove_node(victim)
    assert victim not in g and g.size[0] == nodes - 1 and g.size[1] < edges
    res = g.search(lambda n: Validation(True, margin_m=0.2), ok_edge, Termination(50, 5))
    assert res.status == "solved" and victim not in res.path


# -- the compiled search against networkx's Dijkstra ---------------------------------------------------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from planner.regrasp.graph import SINK, SOURCE  # noqa: E402


def _dual_spec(n_grasps: int, n_placements: int, n_poses: int) -> GraphSpec:
    handovers = [HandoverNode(f, g, t, "right") for f in range(n_poses) for g in range(n_grasps) for t in range(n_grasps)]
    return spec(hands=("right", "left"), grasps=tuple(range(n_grasps)), placements=tuple(range(n_placements)),
                handovers=handovers)


@settings(max_examples=40, deadline=None)
@given(n_grasps=st.integers(1, 4), n_placements=st.integers(3, 4), n_poses=st.integers(0, 2), dual=st.booleans(),
       seed=st.integers(0, 2**31 - 1))
def test_compiled_dijkstra_finds_the_cost_networkx_finds(n_grasps: int, n_placements: int, n_poses: int, dual: bool,
                                                          seed: int) -> None:
    """After random node and edge removals and margin costs (what a lazy search does), the CSR
    search and networkx's Dijkstra on the exported graph agree on the cheapest cost and on
    whether a path exists; the path returned is a real path of that cost."""
    import networkx as nx
    import numpy as np

    rng = np.random.default_rng(seed)
    s = _dual_spec(n_grasps, n_placements, n_poses) if dual else spec(grasps=tuple(range(n_grasps)),
                                                                      placements=tuple(range(n_placements)))
    g = RegraspGraph(s)
    real = [n for n in g.nodes() if isinstance(n, (PlacementNode, HandoverNode))]
    for n in real:
        r = rng.random()
        if r < 0.2:
            g.remove_node(n)
        elif r < 0.6:
            g._apply_margin_cost(n, float(rng.uniform(-0.02, 0.2)))
    exported = g.to_networkx()
    for a, b in list(exported.edges)[: len(exported.edges) // 10]:
        if rng.random() < 0.5:
            g.remove_edge(a, b)
    exported = g.to_networkx()
    found = g.shortest()
    try:
        reference = nx.dijkstra_path_length(exported, SOURCE, SINK, weight="weight")
    except nx.NetworkXNoPath:
        reference = None
    if reference is None:
        assert found is None
        return
    assert found is not None
    path, cost = found
    assert cost == pytest.approx(reference, rel=1e-12, abs=1e-12)
    assert path[0] == SOURCE and path[-1] == SINK
    assert sum(exported.edges[a, b]["weight"] for a, b in zip(path[:-1], path[1:])) == pytest.approx(cost, abs=1e-12)
