"""Direct handover nodes (``handover_direct_pairs_per_pose``): where a handover configuration's best plan puts
the object down on a table before it hands over, the search runs again with handover nodes that join the grasps
the task starts and ends with, and a cheaper direct handover is kept."""

from __future__ import annotations

import numpy as np
import pytest

from planner.jobs.plan_job import build_task
from planner.regrasp.graph import HandoverNode
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.settings import PlannerSettings
from planner.scene.scenarios import load_builtin

#: one-legged (seed 1) picks with the right hand and places with the left; with the evenly spread pairs alone its
#: plan regrasps on a table before the handover
SCENARIO, HANDS = "one-legged", "right-left"


def _planner(direct: int) -> HandConfigPlanner:
    settings = PlannerSettings(handover_direct_pairs_per_pose=direct, parallel_motions=False)
    return HandConfigPlanner(build_task(load_builtin(SCENARIO), settings), HANDS)


def _releases_before_handover(pieces) -> int:
    """Retreats (a hand letting go) before the first handover piece: a table regrasp on the way."""
    kinds = [p.kind for p in pieces]
    return kinds[: kinds.index("handover")].count("retreat")


@pytest.fixture(scope="module")
def planned():
    out = {}
    for direct in (0, PlannerSettings().handover_direct_pairs_per_pose):
        p = _planner(direct)
        out[direct] = (p, p.plan())
    return out


def test_a_table_regrasp_before_the_handover_gives_way_to_a_direct_handover(planned):
    (p0, without), (p, with_direct) = planned[0], planned[PlannerSettings().handover_direct_pairs_per_pose]
    assert without.status == with_direct.status == "solved"
    assert _releases_before_handover(without.pieces) > 0, "the premise: without the direct nodes it regrasps"
    assert p0.direct_handover_nodes == 0
    assert p.direct_handover_nodes > 0
    assert _releases_before_handover(with_direct.pieces) == 0
    assert with_direct.cost < without.cost
    assert with_direct.stats["direct_handover_nodes"] == p.direct_handover_nodes


def test_direct_nodes_join_usable_pairs_of_start_and_goal_grasps(planned):
    p, _ = planned[PlannerSettings().handover_direct_pairs_per_pose]
    t = p.task
    spec = p.screen(p.graph_spec())  # the screening's verdicts are cached: the same spec the plan searched
    base = set(spec.handover_nodes)
    added = [n for n in p.with_direct_handovers(spec).handover_nodes if n not in base]
    assert len(added) == p.direct_handover_nodes > 0
    starts = {n.grasp for n in spec.placement_nodes if n.placement == t.start_id and n.hand == p.start_hand}
    goals = {n.grasp for n in spec.placement_nodes if n.placement == t.goal_id and n.hand == p.goal_hand}
    poses = p.data.handover_poses(t)
    per_pose: dict[int, int] = {}
    for n in added:
        assert isinstance(n, HandoverNode) and n.giver == p.start_hand
        assert n.giver_grasp in starts and n.taker_grasp in goals
        right, left = (n.giver_grasp, n.taker_grasp) if n.giver == "right" else (n.taker_grasp, n.giver_grasp)
        assert ((poses[n.pose].every_pair == (right, left)).all(axis=1)).any()  # the hands clear each other there
        per_pose[n.pose] = per_pose.get(n.pose, 0) + 1
    assert max(per_pose.values()) <= t.settings.handover_direct_pairs_per_pose
    assert np.all([len(hp.pairs) <= t.settings.handover_pairs_per_pose for hp in poses])


def test_a_single_arm_configuration_gets_no_direct_nodes():
    p = HandConfigPlanner(build_task(load_builtin(SCENARIO), PlannerSettings(parallel_motions=False)), "right-right")
    spec = p.screen(p.graph_spec())
    assert p.with_direct_handovers(spec) is spec and p.direct_handover_nodes == 0
