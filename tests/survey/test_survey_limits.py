"""Effort and grip in the survey: a pose over a limit counts as unstable and in the row's over_limits."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from planner.regrasp.settings import PlannerSettings
from planner.regrasp.task import Task
from planner.scene.scenarios import load_scenario, parse_scenario
from planner.survey.runner import run_survey

DATA = Path(__file__).resolve().parents[1] / "data"


def _scenario():
    data = load_scenario(DATA / "small-box.yaml").model_dump(by_alias=True)
    data["object"]["mass_kg"] = 6.0
    return parse_scenario(data)


@pytest.fixture(scope="module")
def weak_survey(hrp5p):
    """The heavy small box surveyed (right-right, 150 states) by a robot whose right wrist is weak: (scenario, the
    weak robot, the survey document, its outcomes with their states)."""
    sc = _scenario()
    weak = dataclasses.replace(hrp5p, spec=hrp5p.spec.model_copy(
        update={"effort_limits": {**hrp5p.spec.effort_limits, "RWRP": 12.0}}))
    doc, out = run_survey(sc, states=150, hands=["right-right"], workers=1, task=Task(sc, robot=weak))
    return sc, weak, doc, out


def test_poses_over_a_limit_are_unstable_and_counted(weak_survey):
    sc, weak, with_limits, out = weak_survey
    row = with_limits["rows"][0]
    assert row["over_limits"] is not None and row["over_limits"] > 0
    assert row["unstable"] >= row["over_limits"]
    # every recorded pose over a limit is recorded unstable
    o = out[0]
    task = Task(sc, robot=weak)
    from planner.survey.limits import over_limits

    flagged = [over_limits(task.limits, o.q[i:i + 1], o.holding[i:i + 1], o.object_pose[i:i + 1]) for i in range(len(o.q))]
    assert not np.any(np.array(flagged, dtype=bool) & o.stable_flags)
    assert sum(flagged) == row["over_limits"]
    free, _ = run_survey(sc, states=150, hands=["right-right"], workers=1,
                         task=Task(sc, PlannerSettings(limits=False), robot=weak))
    assert free["rows"][0]["over_limits"] is None and free["limits"] == "off"
    assert with_limits["limits"] == "effort and grip"


def test_over_limits_polls_the_cancel_between_batches_and_counts_the_same(weak_survey, monkeypatch):
    """A long seed's poses go through the limits in batches with the cancel polled before each: the count does
    not depend on the batch size, and a cancel stops the count with :class:`Canceled`."""
    from planner.errors import Canceled
    from planner.survey import limits as survey_limits

    sc, weak, _, out = weak_survey
    task = Task(sc, robot=weak)
    o = out[0]
    whole = survey_limits.over_limits(task.limits, o.q, o.holding, o.object_pose)
    assert whole > 0 and len(o.q) > 3 * 7
    monkeypatch.setattr(survey_limits, "OVER_LIMITS_BATCH", 7)
    polls: list[int] = []

    def count_polls() -> bool:
        polls.append(1)
        return False

    assert survey_limits.over_limits(task.limits, o.q, o.holding, o.object_pose, count_polls) == whole
    assert len(polls) >= len(o.q) // 7  # one poll per batch, every label's batches
    asked: list[int] = []

    def stop_on_third() -> bool:
        asked.append(1)
        return len(asked) >= 3

    with pytest.raises(Canceled):
        survey_limits.over_limits(task.limits, o.q, o.holding, o.object_pose, stop_on_third)
    assert len(asked) == 3  # it stopped at the poll that asked, not at the end
