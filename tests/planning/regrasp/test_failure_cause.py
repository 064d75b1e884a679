"""One enum for why the planner refused something, from the check to the plan document."""

from __future__ import annotations

import json
from collections import Counter

from planner.regrasp.failure_cause import FailureCause
from planner.regrasp.graph import _dominant_code


def test_a_cause_reads_and_serialises_as_its_value():
    failures = Counter({FailureCause.COM_MARGIN: 3, FailureCause.IK: 1})
    assert repr(dict(failures)) == "{'com_margin': 3, 'ik': 1}"  # messages list failures as before
    assert json.dumps(failures, sort_keys=True) == '{"com_margin": 3, "ik": 1}'
    assert f"{FailureCause.COLLISION}" == "collision" and FailureCause("grip") is FailureCause.GRIP
    assert Counter({"com_margin": 2})[FailureCause.COM_MARGIN] == 2  # counts read by either name


def test_every_cause_has_its_failure_code_and_the_dominant_one_decides():
    assert {c.code for c in FailureCause} == {"IK_FAIL", "COLLISION", "COM_MARGIN", "MOTION", "EFFORT", "GRIP"}
    assert _dominant_code(Counter({FailureCause.IK: 2, FailureCause.COLLISION: 5})) == "COLLISION"
    assert _dominant_code(Counter({"unlisted": 5})) == "NO_PATH"
