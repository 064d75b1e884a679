"""The lazy regrasp graph search with mock validators (no robot needed)."""

from __future__ import annotations

import pytest

from planner.regrasp_graph import (
    Canceled,
    GraphSpec,
    GraphWeights,
    HandoverNode,
    PlacementNode,
    RegraspGraph,
    Validation,
)


def spec(hands=("right", "right"), grasps=(0, 1, 2), placements=(0, 1, 2), handovers=()):
    positions = {p: (0.4, -0.3 + 0.3 * p, 0.8) for p in placements}
    nodes = [PlacementNode(p, g, h) for p in placements for g in grasps for h in ("left", "right")]
    return GraphSpec(start=0, goal=2, positions=positions, placement_nodes=nodes,
                     handover_nodes=list(handovers), start_hand=hands[0], goal_hand=hands[1])


def ok_edge(a, b, kind):
    return Validation(True)


def test_direct_transfer_is_the_cheapest_path():
    g = RegraspGraph(spec())
    res = g.search(lambda n: Validation(True, margin_m=0.2), ok_edge, max_iterations=50, time_limit_s=5)
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

    res = RegraspGraph(spec()).search(node, ok_edge, max_iterations=100, time_limit_s=5)
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

    res = RegraspGraph(spec()).search(lambda n: Validation(True, margin_m=0.2), edge, max_iterations=100, time_limit_s=5)
    assert res.status == "solved" and res.failures["motion"] >= 1
    assert all(n.grasp not in failed for n in res.path)


def test_margin_cost_prefers_the_more_stable_node():
    margins = {0: 0.01, 1: 0.09, 2: 0.05}
    res = RegraspGraph(spec(), GraphWeights(margin=5.0)).search(
        lambda n: Validation(True, margin_m=margins[n.grasp]), ok_edge, max_iterations=100, time_limit_s=5)
    assert res.path[0].grasp == 1


def test_infeasible_returns_reasons_not_an_exception():
    res = RegraspGraph(spec()).search(lambda n: Validation(False, "com_margin"), ok_edge, max_iterations=500, time_limit_s=5)
    assert res.status == "infeasible"
    assert res.code == "COM_MARGIN" and res.failures["com_margin"] > 0


def test_iteration_cap_bounds_the_search():
    res = RegraspGraph(spec()).search(lambda n: Validation(False, "ik"), ok_edge, max_iterations=3, time_limit_s=5)
    assert res.status == "infeasible" and res.iterations == 3


def test_dual_arm_goes_through_a_handover():
    handovers = [HandoverNode(0, gr, gl, "right") for gr in (0, 1) for gl in (1, 2)]
    res = RegraspGraph(spec(hands=("right", "left"), handovers=handovers)).search(
        lambda n: Validation(True, margin_m=0.2), ok_edge, max_iterations=50, time_limit_s=5)
    assert res.status == "solved"
    kinds = [n.kind for n in res.path]
    assert kinds == ["pg", "ho", "pg"]
    assert res.path[0].hand == "right" and res.path[-1].hand == "left"
    assert res.path[0].grasp == res.path[1].giver_grasp and res.path[2].grasp == res.path[1].taker_grasp


def test_single_arm_never_uses_the_other_hand():
    res = RegraspGraph(spec(hands=("left", "left"))).search(lambda n: Validation(True, margin_m=0.2), ok_edge,
                                                          max_iterations=50, time_limit_s=5)
    assert all(n.hand == "left" for n in res.path)


def test_cancel_raises():
    with pytest.raises(Canceled):
        RegraspGraph(spec()).search(lambda n: Validation(True), ok_edge, max_iterations=50, time_limit_s=5,
                                    should_stop=lambda: True)


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
    res = g.search(lambda n: Validation(True, margin_m=0.2), ok_edge, max_iterations=50, time_limit_s=5)
    assert res.status == "solved" and victim not in res.path
