"""Fixtures the regrasp tests share."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="session")
def solved():
    """The small box task (tests/data/small-box.yaml) and its search's own pieces, each timed rest to rest: what
    the plan's timing starts from. Read only: tests that change a plan change copies."""
    from planner.jobs.plan_job import build_task
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.scene.scenarios import load_scenario

    scenario = load_scenario(DATA / "small-box.yaml")
    task = build_task(scenario)
    res = HandConfigPlanner(task, scenario.hands).plan()
    assert res.status == "solved"
    return task, res.pieces
