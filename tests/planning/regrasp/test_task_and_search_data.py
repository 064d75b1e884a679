"""The task apart from the search's scratch (pinocchio's Model/Data): the task is immutable once built,
validations and probes write only into the search's data, and two searches over one task share nothing
they did not hand over."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.regrasp.graph import PlacementNode
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.node_validation import validate_placement
from planner.regrasp.probes import probe_grasps
from planner.regrasp.search_data import SearchData
from planner.regrasp.task import Task
from planner.scene.scenarios import load_scenario

SMALL_BOX = Path(__file__).resolve().parents[2] / "data" / "small-box.yaml"


@pytest.fixture(scope="module")
def task():
    return Task(load_scenario(SMALL_BOX))


def test_the_task_refuses_changes_once_built(task):
    with pytest.raises(AttributeError, match="immutable"):
        task.threshold_m = 0.0
    with pytest.raises(ValueError):
        task.home[0] = 1.0  # the shared home posture is read-only
    with pytest.raises(TypeError):
        task.grasps["left"] = ()  # type: ignore[index]


def test_validations_and_probes_write_into_the_search_data_only(task):
    before = {k: id(v) for k, v in vars(task).items()}
    home = task.home.copy()
    data = SearchData(task)
    planner = HandConfigPlanner(task, "right-right", data=data)
    nodes = [n for n in planner.graph_spec().placement_nodes if isinstance(n, PlacementNode)][:20]
    probes = probe_grasps(task, data, nodes)
    verdicts = [validate_placement(task, data, n, np.random.default_rng(task.node_seed(n))) for n in nodes[:6]]
    assert set(probes) >= set(nodes) and data.grasp_probes
    assert data.counters["ik_solves"] > 0 and data.counters["com_states"] > 0
    assert any(v.ok for v in verdicts) or any(v.cause for v in verdicts)
    assert {k: id(v) for k, v in vars(task).items()} == before  # the same objects, none rebound
    assert np.array_equal(task.home, home)


def test_two_searches_over_one_task_share_only_what_is_handed_over(task):
    planner = HandConfigPlanner(task, "left-left")
    nodes = [n for n in planner.graph_spec().placement_nodes if isinstance(n, PlacementNode)][:10]
    probe_grasps(task, planner.data, nodes)
    other = SearchData(task)
    assert not other.grasp_probes and not other.node_cache and other.counters["ik_solves"] == 0
    other.adopt(planner.data.validations())
    assert set(other.grasp_probes) == set(planner.data.grasp_probes)
    for n in nodes:
        mine, theirs = planner.data.grasp_probes[n], other.grasp_probes[n]
        assert (mine.q is None) == (theirs.q is None)
        assert mine.q is None or np.array_equal(mine.q, theirs.q)


def test_failed_validations_carry_a_failure_cause(task):
    from planner.regrasp.failure_cause import FailureCause

    data = SearchData(task)
    planner = HandConfigPlanner(task, "left-left", data=data)
    nodes = [n for n in planner.graph_spec().placement_nodes if isinstance(n, PlacementNode)][:30]
    probe_grasps(task, data, nodes)
    verdicts = list(data.node_cache.values()) + [
        validate_placement(task, data, n, np.random.default_rng(task.node_seed(n))) for n in nodes[:10]]
    failed = [v for v in verdicts if not v.ok]
    assert failed and all(isinstance(v.cause, FailureCause) for v in failed)
