"""The gate reads plan bytes with orjson (schemas.fast_json); hashes stay those of json.dumps (schemas.plan.canonical_json)."""

from __future__ import annotations

import hashlib
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_bridge.gate import SafetyGate
from schemas.plan import canonical_json, plan_sha256

from .plans import build_plan

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
json_values = st.recursive(
    st.none() | st.booleans() | finite | st.integers(-(2**63), 2**63 - 1) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(doc=st.dictionaries(st.text(max_size=6), json_values, max_size=6))
def test_a_document_parsed_fast_and_hashed_again_has_the_stored_hash(doc):
    from schemas.fast_json import loads

    stored = canonical_json(doc)
    assert canonical_json(loads(stored)) == stored
    assert plan_sha256(loads(stored)) == hashlib.sha256(stored).hexdigest()


def test_a_real_plan_parsed_fast_keeps_its_hash():
    from robot_bridge.gate import loads_plan

    plan = build_plan({"RSP": -0.5, "WY": 0.2}, duration_s=0.5, holding="right", mass_kg=3.0)
    stored = canonical_json(plan)
    sha = hashlib.sha256(stored).hexdigest()
    assert plan_sha256(loads_plan(stored)) == sha
    # Every float reads back as the same double (the fast writer's spelling would differ: never hashed).
    assert loads_plan(stored) == json.loads(stored)


@pytest.mark.parametrize("text", ['{"a": NaN}', '{"a": Infinity}', '{"a": -Infinity}'])
def test_non_finite_literals_are_refused_as_before(text):
    from robot_bridge.gate import loads_plan

    with pytest.raises(ValueError, match="is not a number the plan may hold"):
        loads_plan(text.encode())


def test_what_orjson_refuses_reads_as_json_loads_reads_it():
    from schemas.fast_json import loads

    big = '{"n": 123456789012345678901234567890, "s": "\\ud800"}'
    assert loads(big) == json.loads(big)
    with pytest.raises(ValueError):
        loads(b'{"a": [1, 2')


def test_check_json_verdicts_equal_check_on_the_parsed_plan():
    plan = build_plan({"RSP": -0.3}, duration_s=1.0)
    gate = SafetyGate()
    v_json, parsed = gate.check_json(canonical_json(plan), offline=True)
    v_dict = gate.check(plan, offline=True)
    assert parsed == plan and v_dict.passed, v_dict.message
    assert (v_json.passed, v_json.check, v_json.sample_index, v_json.plan_sha256) == \
        (v_dict.passed, v_dict.check, v_dict.sample_index, v_dict.plan_sha256)
    assert v_json.stats["com_margin"]["min_margin_m"] == v_dict.stats["com_margin"]["min_margin_m"]
    assert math.isfinite(v_json.stats["timing"]["json_s"])
    bad = canonical_json(plan).replace(b'"dt_s":0.005', b'"dt_s":NaN')
    v_bad, _ = gate.check_json(bad, offline=True)
    assert not v_bad.passed and v_bad.check == "structure" and "not valid JSON" in v_bad.message
