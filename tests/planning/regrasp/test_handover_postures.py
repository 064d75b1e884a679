"""Other giver postures (``handover_giver_postures``): a giver whose first posture at a handover pose collides
gets another that passes (the probe), and a node whose exchange collides with the giver as first solved is valid
with another (the node's validation); what each carries holds the object where the handover pose has it and
passes the task's own checks."""

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
def probed():
    """The graph's handover nodes probed with the first giver posture only and with the default retries:
    ``postures -> (planner, nodes)``."""
    out = {}
    for postures in (0, PlannerSettings().handover_giver_postures):
        p = _planner(postures)
        nodes = p.graph_spec().handover_nodes
        probe_givers(p.task, p.data, nodes)
        out[postures] = (p, nodes)
    return out


@pytest.fixture(scope="module")
def verdicts(probed):
    """The same handover nodes (those whose giver's first posture passes) validated with the first giver posture
    only and with the default retries."""
    p0, nodes = probed[0]
    passing = [n for n in nodes if (g := p0.data.giver_at.get((n.pose, n.giver_grasp, n.giver))) is not None
               and g[2] is None][:NODES]
    out = {}
    for postures, (p, _) in probed.items():
        t, d = p.task, p.data
        out[postures] = (t, d, {n: validate_handover(t, d, n, np.random.default_rng(t.node_seed(n))) for n in passing})
    return out


def _holds_at_pose(t, d, n: HandoverNode, q: np.ndarray) -> None:
    """The giver's hand in ``q`` holds the object where the handover pose has it, with the giver's grasp, within
    the IK's tolerances (its rotation tolerance bounds each component of the rotation error)."""
    T_want = d.handover_poses(t)[n.pose].T_world_obj @ t.grasps[n.giver][n.giver_grasp].T_obj_tcp
    T_got = t.tcp(q, n.giver)
    ik = t.settings.ik
    assert np.linalg.norm(T_got[:3, 3] - T_want[:3, 3]) <= np.sqrt(3) * ik.pos_tol_m
    cos = np.clip((np.trace(T_got[:3, :3].T @ T_want[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    assert np.arccos(cos) <= np.sqrt(3) * ik.rot_tol_rad


def test_a_giver_whose_first_posture_collides_passes_with_another(probed):
    (p0, nodes), (p, _) = probed[0], probed[PlannerSettings().handover_giver_postures]
    keys = list(dict.fromkeys((n.pose, n.giver_grasp, n.giver) for n in nodes))
    first, retried = p0.data.giver_at, p.data.giver_at
    rescued = [k for k in keys if first[k] is not None and first[k][2] == FailureCause.COLLISION
               and retried[k][2] is None]
    assert rescued, "no giver whose first posture collides passes with another"
    assert p.data.counters["giver_postures_rescued"] == len(rescued)
    assert p0.data.counters["giver_postures_tried"] == 0
    for k in keys:
        if first[k] is None or first[k][2] != FailureCause.COLLISION:  # only colliding postures are retried
            assert (first[k] is None) == (retried[k] is None)
            if first[k] is not None:
                assert np.array_equal(first[k][0], retried[k][0]) and first[k][2] == retried[k][2]
    t, d = p.task, p.data
    for k in rescued:
        q, hold = retried[k][0], retried[k][1]
        assert not np.allclose(q, first[k][0], atol=1e-3)
        _holds_at_pose(t, d, HandoverNode(k[0], k[1], 0, k[2]), q)
        cause, margin = d.checker.classify(q[None], hold, None)  # collision-free, and the margin kept
        assert cause is None and margin >= t.threshold_m


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
        _holds_at_pose(t, d, n, hp.q_giver_at)  # the other posture holds the object where the pose has it
        # Every state of its exchange passes the task's checker again (collision and margin); the fingers of the
        # hand closing or opening may touch the object. A transit's path is planned later between its two ends.
        touching = [None, n.taker, n.taker, n.giver, n.giver, None]
        for piece, grasping in zip(hp.pieces, touching, strict=True):
            states = piece.waypoints[[0, -1]] if piece.kind == "transit" else piece.waypoints
            cause, margin = d.checker.classify(states, piece.hold, None, grasping=grasping)
            assert cause is None, (n, piece.kind, cause)
            assert margin >= t.threshold_m
