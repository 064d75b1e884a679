"""The regrasp planner end to end on small tasks; every solved plan is re-verified independently."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner.jobs import PlanningInputError, PlanOptions, plan_scenario
from planner.scenarios import load_scenario, with_overrides
from schemas.plan import Plan, plan_sha256
from plan_checker import check_plan

DATA = Path(__file__).parent.parent / "data"


@pytest.fixture(scope="module")
def small_box():
    return load_scenario(DATA / "small-box.yaml")


@pytest.fixture(scope="module")
def small_plan(small_box):
    return plan_scenario(small_box, PlanOptions())


def test_solved_plan_passes_the_independent_checker(small_plan):
    assert small_plan["status"] == "solved", small_plan["failure"]
    Plan.model_validate(small_plan)  # the wire schema
    report = check_plan(small_plan)
    assert report.errors == []
    assert report.min_margin >= small_plan["threshold_m"] - 1e-4
    kinds = [s["kind"] for s in small_plan["segments"]]
    assert "transfer" in kinds and "approach" in kinds and "retreat" in kinds
    holding = {p["holding"] for p in small_plan["trajectory"]}
    assert holding == {"none", "right"}


def test_plan_hash_is_canonical_and_stable(small_plan):
    digest = plan_sha256(small_plan)
    assert len(digest) == 64 and digest == plan_sha256(dict(small_plan))


def test_same_seed_gives_the_same_trajectory(small_box, small_plan):
    again = plan_scenario(small_box, PlanOptions())
    assert [p["q"] for p in again["trajectory"]] == [p["q"] for p in small_plan["trajectory"]]


def test_threshold_beyond_the_polygon_is_infeasible_with_a_reason(small_box):
    doc = plan_scenario(small_box, PlanOptions(threshold_m=0.2))
    assert doc["status"] == "infeasible"
    assert doc["failure"]["code"] == "THRESHOLD_TOO_LARGE" and "inradius" in doc["failure"]["message"]


def test_goal_not_resting_on_a_table_is_rejected(small_box):
    bad = with_overrides(small_box)
    data = bad.model_dump(by_alias=True)
    data["goal_pose"][2] += 0.05
    from planner.scenarios import parse_scenario

    doc = plan_scenario(parse_scenario(data), PlanOptions())
    assert doc["status"] == "infeasible" and doc["failure"]["code"] == "GOAL_INVALID"
    assert "50 mm above table" in doc["failure"]["message"]


def test_object_too_heavy_is_infeasible_within_its_time_limit(small_box):
    from planner.scenarios import parse_scenario

    data = small_box.model_dump(by_alias=True)
    data["object"]["mass_kg"] = 60.0
    data["limits"] = {"time_s": 60, "max_iterations": 50}
    import time

    t0 = time.perf_counter()
    doc = plan_scenario(parse_scenario(data), PlanOptions())
    assert time.perf_counter() - t0 < 60 + 15
    assert doc["status"] == "infeasible"
    assert doc["failure"]["code"] in ("NO_STABLE_GRASP", "COM_MARGIN")
    assert doc["failure"]["counts"].get("com_margin", 0) > 0


def test_unknown_hands_is_a_usage_error(small_box):
    with pytest.raises(PlanningInputError, match="hands"):
        plan_scenario(small_box, PlanOptions(hands="both-hands"))


@settings(max_examples=3, deadline=None, suppress_health_check=list(HealthCheck))
@given(mass=st.floats(0.5, 6.0), com_y=st.floats(-0.04, 0.04), start_y=st.floats(-0.26, -0.18))
def test_plan_is_either_valid_or_infeasible_with_a_reason(small_box, mass, com_y, start_y):
    from planner.scenarios import parse_scenario

    data = small_box.model_dump(by_alias=True)
    data["object"]["mass_kg"] = mass
    data["object"]["com_local"] = [0.0, com_y, 0.0]
    data["start_pose"][1] = start_y
    data["limits"] = {"time_s": 90, "max_iterations": 120}
    doc = plan_scenario(parse_scenario(data), PlanOptions())
    if doc["status"] == "solved":
        assert check_plan(doc).errors == []
    else:
        assert doc["failure"]["code"] and doc["failure"]["message"]
