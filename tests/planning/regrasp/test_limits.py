"""Effort and grip limits in the planner: a task that fails only a limit ends infeasible with its code."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.regrasp.settings import PlannerSettings
from planner.regrasp.task import Task
from planner.robot.spec import GripSpec
from planner.scene.scenarios import load_scenario, parse_scenario
from plan_checker import check_plan

DATA = Path(__file__).resolve().parents[2] / "data"
WRIST = ["RWRY", "RWRR", "RWRP", "RHDY"]


@pytest.fixture(scope="module")
def heavy_box():
    """small-box with 6 kg: within the CoM threshold and hrp5p's limits."""
    data = load_scenario(DATA / "small-box.yaml").model_dump(by_alias=True)
    data["object"]["mass_kg"] = 6.0
    data["limits"] = {"time_s": 120, "max_iterations": 150}
    return parse_scenario(data)


def _variant(robot, **update):
    """The robot with parts of its spec replaced (a weak wrist, a slippery grip)."""
    return dataclasses.replace(robot, spec=robot.spec.model_copy(update=update))


def test_a_weak_wrist_ends_effort_and_the_same_task_plans_without_limits(hrp5p, heavy_box):
    limits = {**hrp5p.spec.effort_limits, **{j: 4.0 for j in WRIST}}
    weak = _variant(hrp5p, effort_limits=limits)
    doc = plan_scenario(heavy_box, PlanOptions(), task=Task(heavy_box, robot=weak))
    assert doc["status"] == "infeasible"
    assert doc["failure"]["code"] == "EFFORT", doc["failure"]
    assert doc["failure"]["counts"]["effort"] > 0
    free = plan_scenario(heavy_box, PlanOptions(), task=Task(heavy_box, PlannerSettings(limits=False), robot=weak))
    assert free["status"] == "solved" and free["stats"]["limits"] is False
    assert max(p["effort_ratio"] for p in free["trajectory"]) > 1.0  # what the limits would have refused


def test_a_slippery_grip_ends_grip(hrp5p, heavy_box):
    slippery = _variant(hrp5p, grip=GripSpec(friction=0.05, force_n=100.0, patch_radius_m=0.01))
    doc = plan_scenario(heavy_box, PlanOptions(), task=Task(heavy_box, robot=slippery))
    assert doc["status"] == "infeasible"
    assert doc["failure"]["code"] == "GRIP", doc["failure"]
    assert doc["failure"]["counts"]["grip"] > 0


def test_a_plan_within_the_limits_carries_effort_ratio_and_passes_the_checker(heavy_box):
    doc = plan_scenario(heavy_box, PlanOptions())
    assert doc["status"] == "solved"
    ratios = [p["effort_ratio"] for p in doc["trajectory"]]
    assert 0.0 < max(ratios) <= 1.0
    assert check_plan(doc, sample_every=5).errors == []
