"""One enum for why the planner refused something, from the check to the plan document."""

from __future__ import annotations

import json
from collections import Counter

from hypothesis import given
from hypothesis import strategies as st

from planner.regrasp.failure_cause import FailureCause, failures_in_words
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


def test_failures_read_as_words_not_a_dict():
    failures = Counter({FailureCause.IK: 5, FailureCause.COLLISION: 7, FailureCause.GRIP: 0})
    assert failures_in_words(failures, "states removed") == "12 states removed (collision 7, IK 5)"
    assert failures_in_words({"com_margin": 3}) == "3 removed (CoM margin 3)"
    assert failures_in_words({}, "refused") == "0 refused"


@given(st.dictionaries(st.sampled_from(list(FailureCause)), st.integers(0, 10_000)))
def test_the_words_carry_every_count_and_their_sum(failures):
    text = failures_in_words(failures)
    assert "{" not in text and "'" not in text
    assert text.startswith(f"{sum(failures.values())} removed")
    for n in failures.values():
        if n:
            assert f" {n}" in text
