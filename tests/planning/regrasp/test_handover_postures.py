"""Other giver postures at a handover node whose exchange collides with the giver as first solved
(``handover_giver_postures``): a node that fails with the first posture only is valid with another, and what it
carries holds the object where the handover pose has it and passes the task's own checks."""

from __future__ import annotations

import numpy as np
import pytest

from planner.jobs.plan_job import build_task
from planner.regrasp.failure_cause import FailureCause
from planner.regrasp.graph import HandoverNode
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.node_validation import validate_handover
from planner.regrasp.probes import probe_givers
from planner.regrasp.settings import PlannerSettings
from planner.scene.scenarios import load_builtin

#: handover nodes looked at (those whose giver alone passes, in the graph's order)
NODES = 60


def _planner(postures: int) -> HandConfigPlanner:
    """Drill-handover's right-left planner (seed 1), with ``postures`` more giver postures."""
    settings = PlannerSettings(handover_giver_postures=postures, parallel_motions=False)
    return HandConfigPlanner(build_task(load_builtin("drill-handover"), settings), "right-left")


@pytest.fixture(scope="module")
def verdicts():
    """The same handover nodes validated with the first giver posture only and with the default retries."""
    out = {}
    for postures in (0, PlannerSettings().handover_giver_postures):
        p = _planner(postures)
        t, d = p.task, p.data
        nodes = p.graph_spec().handover_nodes
        probe_givers(t, d, nodes)
        given = [d.giver_at.get((n.pose, n.giver_grasp, n.giver)) for n in nodes]
        passing = [n for n, g in zip(nodes, given) if g is not None and g[2] is None][:NODES]
        out[postures] = (t, d, {n: validate_handover(t, d, n, np.random.default_rng(t.node_seed(n))) for n in passing})
    return out


def test_a_node_whose_exchange_collides_with_the_first_giver_posture_passes_with_another(verdicts):
    assert PlannerSettings().handover_giver_postures > 0
    (_, d0, first), (t, d, retried) = verdicts[0], verdicts[PlannerSettings().handover_giver_postures]
    assert first.keys() == retried.keys()
    rescued = [n for n in first if not first[n].ok and retried[n].ok]
    assert rescued, "no node the first giver posture fails is valid with another"
    for n, v in first.items():
        if retried[n].ok and not v.ok:
            assert v.cause == FailureCause.COLLISION  # only collisions are retried
        if v.ok:  # a node valid with the first posture keeps it
            assert retried[n].ok
            assert np.array_equal(retried[n].payload.q_giver_at, v.payload.q_giver_at)
        if not v.ok and v.cause != FailureCause.COLLISION:
            assert (retried[n].ok, retried[n].cause, retried[n].detail) == (False, v.cause, v.detail)
    assert d.counters["handover_giver_postures"] > 0 and d0.counters["handover_giver_postures"] == 0
    for n in rescued:
        hp = retried[n].payload
        first_posture = d.giver_at[(n.pose, n.giver_grasp, n.giver)][0]
        assert not np.allclose(hp.q_giver_at, first_posture, atol=1e-3)
        # The other posture holds the object where the handover pose has it, with the giver's grasp.
        T_obj = d.handover_poses(t)[n.pose].T_world_obj
        T_want = T_obj @ t.grasps[n.giver][n.giver_grasp].T_obj_tcp
        T_got = t.tcp(hp.q_giver_at, n.giver)
        assert np.linalg.norm(T_got[:3, 3] - T_want[:3, 3]) < 2e-3
        assert np.linalg.norm(T_got[:3, :3] - T_want[:3, :3]) < 1e-2
        # Every state of its exchange passes the task's checker again (collision and margin); the fingers of the
        # hand closing or opening may touch the object. A transit's path is planned later between its two ends.
        touching = [None, n.taker, n.taker, n.giver, n.giver, None]
        for piece, grasping in zip(hp.pieces, touching, strict=True):
            states = piece.waypoints[[0, -1]] if piece.kind == "transit" else piece.waypoints
            cause, margin = d.checker.classify(states, piece.hold, None, grasping=grasping)
            assert cause is None, (n, piece.kind, cause)
            assert margin >= t.threshold_m
