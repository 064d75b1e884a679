"""The gate reads plan bytes typed (msgspec) or as a document (orjson, schemas.fast_json); hashes stay those of
json.dumps (schemas.plan.canonical_json), and both readings give the same verdict."""

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
    assert v_dict.passed, v_dict.message
    assert_reads_the_plan(parsed, plan)
    assert (v_json.passed, v_json.check, v_json.sample_index, v_json.plan_sha256) == \
        (v_dict.passed, v_dict.check, v_dict.sample_index, v_dict.plan_sha256)
    assert v_json.stats["com_margin"]["min_margin_m"] == v_dict.stats["com_margin"]["min_margin_m"]
    assert math.isfinite(v_json.stats["timing"]["json_s"])
    bad = canonical_json(plan).replace(b'"dt_s":0.005', b'"dt_s":NaN')
    v_bad, _ = gate.check_json(bad, offline=True)
    assert not v_bad.passed and v_bad.check == "structure" and "not valid JSON" in v_bad.message


def assert_reads_the_plan(parsed, plan) -> None:
    """The gate's typed reading holds the plan's checked fields exactly (what the dispatcher sends)."""
    from robot_bridge.gate import ExecutablePlan

    assert isinstance(parsed, ExecutablePlan)
    assert parsed.dt_s == plan["dt_s"] and parsed.robot.joint_names == plan["robot"]["joint_names"]
    assert [(p.t, p.q, p.holding, p.object_pose) for p in parsed.trajectory] == \
        [(p["t"], p["q"], p["holding"], p["object_pose"]) for p in plan["trajectory"]]


def _verdict(v):
    return v.passed, v.check, v.sample_index, v.message


#: Values put in one place of a valid plan: the typed reading refuses most (wrong JSON type), the
#: document reading then names them; some are of the right type but out of range.
ODD_VALUES = st.sampled_from([None, True, False, "1.5", [], {}, -1.0, 0.0, 2.0, 1e308, -1e308, 7, "solved", "both", ""])
PLACES = st.sampled_from([
    ("dt_s",), ("threshold_m",), ("status",), ("schema",), ("robot", "name"), ("robot", "urdf_sha256"),
    ("robot", "joint_names"), ("robot", "joint_names", 0), ("object", "mass_kg"), ("object", "com_local"),
    ("object", "com_local", 1), ("stance", "base_pose"), ("stance", "base_pose", 2), ("stance", "feet"),
    ("stance", "feet", 0, "frame"), ("stance", "feet", 0, "pose", 0), ("stance", "feet", 0, "in_contact"),
    ("trajectory",), ("trajectory", 3, "q", 5), ("trajectory", 3, "q"), ("trajectory", 0, "t"),
    ("trajectory", 5, "holding"), ("trajectory", 2, "object_pose", 6), ("trajectory", 4), ("trajectory", 1, "object_pose"),
])


@pytest.fixture(scope="module")
def small_plan():
    return build_plan({"RSP": -0.3}, duration_s=0.1, holding="right", mass_kg=2.0)


@pytest.fixture(scope="module")
def module_gate():
    return SafetyGate()


@settings(max_examples=120, deadline=None)
@given(place=PLACES, value=ODD_VALUES, drop=st.booleans())
def test_the_typed_reading_gives_the_documents_verdict(small_plan, module_gate, place, value, drop):
    """Whatever one value of the plan is (or when it is missing), check_json's verdict is check()'s on the
    same document: the fast typed reading never accepts what the document reading refuses, nor the reverse."""
    import copy

    doc = copy.deepcopy(small_plan)
    parent = doc
    for key in place[:-1]:
        parent = parent[key]
    if drop and isinstance(parent, dict):
        parent.pop(place[-1], None)
    else:
        parent[place[-1]] = value
    raw = json.dumps(doc).encode()
    v_json, _ = module_gate.check_json(raw, offline=True)
    v_doc = module_gate.check(json.loads(raw), offline=True)
    assert _verdict(v_json) == _verdict(v_doc)


def test_a_plan_the_typed_reading_refuses_is_checked_and_returned_as_a_document():
    """JSON true where a number is (Python's 1) and a foot frame that is not a string: the typed reading
    refuses them, the document reading takes them as check() does, and the document is what is returned."""
    plan = build_plan({"RSP": -0.3}, duration_s=0.2)
    plan["trajectory"][0]["q"][0] = False
    gate = SafetyGate()
    v_json, parsed = gate.check_json(json.dumps(plan).encode(), offline=True)
    assert _verdict(v_json) == _verdict(gate.check(plan, offline=True))
    assert parsed == json.loads(json.dumps(plan))
