"""A cancel inside the batch probes (a stable-posture search per unstable grasp, thousands on a large task):
the probes poll it, raise :class:`Canceled`, and store nothing of the batch they were in, so a search that
goes on with the same data finds what a fresh one finds."""

from __future__ import annotations

from typing import Callable

import numpy as np
import pytest

from planner.errors import Canceled
from planner.regrasp.graph import PlacementNode
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.probes import probe_grasps
from planner.regrasp.search_data import SearchData
from planner.regrasp.task import Task
from planner.scene.scenarios import load_builtin


@pytest.fixture(scope="module")
def task():
    """The upright scenario: many of its grasps hold the object unstably and need a stable-posture search."""
    return Task(load_builtin("upright"))


def _polls(stop_at: int | None) -> tuple[list[int], Callable[[], bool]]:
    """A cancel predicate counting its polls; it asks to stop from poll ``stop_at`` on (None: never)."""
    polls: list[int] = []

    def canceled() -> bool:
        polls.append(1)
        return stop_at is not None and len(polls) >= stop_at

    return polls, canceled


def _nodes(task: Task) -> list[PlacementNode]:
    spec = HandConfigPlanner(task, "right-right").graph_spec()
    return [n for n in spec.placement_nodes if isinstance(n, PlacementNode)]


def _same_probes(a: SearchData, b: SearchData) -> None:
    assert set(a.grasp_probes) == set(b.grasp_probes)
    for n, p in a.grasp_probes.items():
        q = b.grasp_probes[n]
        assert (p.q is None) == (q.q is None) and p.margin_m == q.margin_m
        assert p.q is None or np.array_equal(p.q, q.q)
    assert {n: (v.ok, v.cause) for n, v in a.node_cache.items()} == {n: (v.ok, v.cause) for n, v in b.node_cache.items()}


def test_a_cancel_inside_the_grasp_probes_stops_them_and_stores_no_partial_batch(task):
    nodes = _nodes(task)
    reference = SearchData(task)
    polls, counting = _polls(None)
    probe_grasps(task, reference, nodes, counting)
    assert len(polls) >= 4  # the probes searched stable postures, each after a poll

    data = SearchData(task)
    asked, cancel = _polls(len(polls) // 2)
    with pytest.raises(Canceled):
        probe_grasps(task, data, nodes, cancel)
    assert len(asked) == len(polls) // 2  # it stopped at the poll that asked
    for side in ("left", "right"):  # a hand's batch is stored whole or not at all
        mine = [n for n in nodes if n.hand == side]
        stored = [n for n in mine if n in data.grasp_probes]
        assert not stored or len(stored) == len(mine), side
        assert stored or not any(n in data.node_cache for n in mine), side
    assert len(data.grasp_probes) < len(reference.grasp_probes)

    probe_grasps(task, data, nodes)  # the search goes on with the same data
    _same_probes(data, reference)


def test_a_cancel_during_a_search_preparation_leaves_the_next_search_unchanged(task):
    """Through the planner: its termination's cancel reaches the probes of ``prepare_search``."""
    from planner.regrasp.graph import RegraspGraph
    from planner.termination import Termination

    fresh = HandConfigPlanner(task, "right-right")
    fresh.prepare_search(RegraspGraph(fresh.graph_spec(), task.settings.weights))

    data = SearchData(task)
    asked, cancel = _polls(3)
    stopped = HandConfigPlanner(task, "right-right", Termination(100, canceled=cancel), data=data)
    with pytest.raises(Canceled):
        stopped.prepare_search(RegraspGraph(stopped.graph_spec(), task.settings.weights))
    assert len(asked) == 3
    again = HandConfigPlanner(task, "right-right", data=data)
    again.prepare_search(RegraspGraph(again.graph_spec(), task.settings.weights))
    _same_probes(data, fresh.data)
