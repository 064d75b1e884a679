"""The gate enforces the site's safety policy (schemas.policy): a plan made below the margin floor is vetoed,
every sample is checked against the larger of the threshold and the floor, no argument lowers the floor, the
mass and speed caps hold, and every verdict carries the policy's SHA-256. Offline, through ``regrasp gate
check``, the same built-in floor applies."""

from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robot_bridge.gate import GateSettings, SafetyGate
from schemas.policy import SafetyPolicy, default_policy

from .plans import build_plan, true_min_margin

#: The margin alone: the torque and grip checks are tested in test_gate_effort.
MARGIN_ONLY = GateSettings(check_limits=False)


@pytest.fixture(scope="module")
def plan() -> dict:
    """A short arm swing planned at the built-in floor (30 mm), holding a 2 kg object in the right hand."""
    return build_plan({"RSP": -0.4}, duration_s=1.5, threshold_m=0.03, holding="right", mass_kg=2.0)


def test_a_plan_made_below_the_floor_is_vetoed_naming_the_policy(plan):
    gate = SafetyGate(MARGIN_ONLY)
    below = {**plan, "threshold_m": 0.0}
    v = gate.check(below, offline=True)
    assert not v.passed and v.check == "policy", v.summary()
    assert "0.0 mm" in v.message and "30.0 mm floor" in v.message and "built-in safety policy" in v.message
    assert default_policy().sha256()[:12] in v.message and v.policy_sha256 == default_policy().sha256()
    assert gate.check(plan, offline=True).passed  # at the floor it passes


def test_no_threshold_given_to_the_gate_lowers_the_floor(plan):
    """The margin is judged against max(threshold, floor): a threshold below the floor given to the check
    (as ``--threshold-mm`` does) is raised to the floor, so a plan whose true margin is under the floor fails."""
    true = true_min_margin(plan)
    strict = SafetyPolicy(margin_floor_m=true + 0.002)  # a floor just above what the plan keeps
    planned_at_floor = {**plan, "threshold_m": strict.margin_floor_m}
    v = SafetyGate(MARGIN_ONLY, policy=strict).check(planned_at_floor, offline=True, threshold_m=0.0)
    assert not v.passed and v.check == "com_margin", v.summary()
    assert v.threshold_m == strict.margin_floor_m
    assert f"{strict.margin_floor_m * 1000:.2f} mm" in v.message
    lenient = SafetyPolicy(margin_floor_m=true - 0.002)
    v = SafetyGate(MARGIN_ONLY, policy=lenient).check({**plan, "threshold_m": lenient.margin_floor_m}, offline=True,
                                                      threshold_m=0.0)
    assert v.passed and v.threshold_m == lenient.margin_floor_m, v.summary()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(floor=st.floats(0.0, 0.08), plan_threshold=st.floats(0.0, 0.08), asked=st.none() | st.floats(0.0, 0.08))
def test_the_verdicts_threshold_is_never_below_the_floor(plan, floor, plan_threshold, asked):
    policy = SafetyPolicy(margin_floor_m=floor)
    v = SafetyGate(MARGIN_ONLY, policy=policy).check({**plan, "threshold_m": plan_threshold}, offline=True,
                                                     threshold_m=asked)
    assert v.policy_sha256 == policy.sha256()
    if plan_threshold < floor - 1e-12:
        assert not v.passed and v.check == "policy"
    else:
        assert v.threshold_m is not None and v.threshold_m >= floor
        assert v.threshold_m == max(plan_threshold if asked is None else asked, floor)


def test_the_mass_and_speed_caps(plan):
    heavy = SafetyGate(MARGIN_ONLY, policy=SafetyPolicy(max_object_mass_kg=1.5))
    v = heavy.check(plan, offline=True)
    assert not v.passed and v.check == "policy" and "2.00 kg" in v.message and "1.50 kg" in v.message
    assert v.sample_index == 0  # held from the first point
    assert SafetyGate(MARGIN_ONLY, policy=SafetyPolicy(max_object_mass_kg=2.5)).check(plan, offline=True).passed
    not_held = build_plan({"RSP": -0.4}, duration_s=1.5, threshold_m=0.03, mass_kg=2.0)
    assert heavy.check(not_held, offline=True).passed  # the cap is on what the hands hold

    slow = SafetyGate(MARGIN_ONLY, policy=SafetyPolicy(max_speed_scale=0.5))
    timed = {**plan, "timing": {"method": "test", "speed_scale": 0.8, "duration_s": 0.7}}
    v = slow.check(timed, offline=True)
    assert not v.passed and v.check == "policy" and "speed_scale 0.8" in v.message and "at most 0.5" in v.message
    assert slow.check({**timed, "timing": {**timed["timing"], "speed_scale": 0.5}}, offline=True).passed
    assert slow.check(plan, offline=True).passed  # a plan without timing has no speed scale to cap
    v = slow.check({**timed, "timing": {"speed_scale": float("nan")}}, offline=True)
    assert not v.passed and v.check in ("structure", "finite")
    # The same verdict from the plan's bytes (the dispatcher's path) as from the document.
    from schemas.plan import canonical_json

    by_bytes, _ = slow.check_json(canonical_json(timed), offline=True)
    by_doc = slow.check(timed, offline=True)
    assert (by_bytes.passed, by_bytes.check, by_bytes.message) == (False, "policy", by_doc.message)


def test_a_required_physics_dry_run(plan):
    policy = SafetyPolicy(require_physics_pass=True, min_cop_margin_m=0.02)
    gate = SafetyGate(MARGIN_ONLY, policy=policy)
    v = gate.check(plan, offline=True)
    assert v.passed and "physics_dry_run" in v.skipped  # the gate runs no physics; the service holds the report
    sha = v.plan_sha256
    stood = {"plan_sha256": sha, "fell": False, "fault": None, "min_cop_margin_m": 0.03}
    assert gate.check(plan, offline=True, physics=stood).passed
    assert gate.check(plan, offline=True, physics={**stood, "min_cop_margin_m": 0.01}).check == "policy"
    assert gate.check(plan, offline=True, physics={**stood, "fell": True}).check == "policy"
    assert gate.check(plan, offline=True, physics={**stood, "plan_sha256": "0" * 64}).check == "policy"


def test_gate_check_cli_uses_the_policy(tmp_path, plan, monkeypatch):
    from click.testing import CliRunner

    from service.cli.main import cli

    low = tmp_path / "low.json"
    low.write_text(json.dumps({**plan, "threshold_m": 0.0}))
    runner = CliRunner()
    monkeypatch.delenv("REGRASP_POLICY", raising=False)
    out = runner.invoke(cli, ["gate", "check", str(low)])
    assert out.exit_code == 1 and "policy" in out.stdout and "30.0 mm floor" in out.stdout, out.output
    # A threshold given on the command line does not lower the floor either.
    out = runner.invoke(cli, ["gate", "check", str(low), "--threshold-mm", "0", "--json"])
    assert out.exit_code == 1 and json.loads(out.stdout)["check"] == "policy"
    # A site that allows a lower floor says so in its policy file, by flag or by environment.
    lenient = tmp_path / "lenient.yaml"
    lenient.write_text("schema: regrasp.policy/1\nmargin_floor_m: 0.0\n")
    out = runner.invoke(cli, ["gate", "check", str(low), "--policy", str(lenient), "--json"])
    doc = json.loads(out.stdout)
    assert out.exit_code == 0 and doc["passed"], out.output
    assert doc["policy_sha256"] == SafetyPolicy(margin_floor_m=0.0).sha256()
    monkeypatch.setenv("REGRASP_POLICY", str(lenient))
    assert runner.invoke(cli, ["gate", "check", str(low)]).exit_code == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("schema: regrasp.policy/1\nmargin_floor_m: -1\n")
    out = runner.invoke(cli, ["gate", "check", str(low), "--policy", str(bad)])
    assert out.exit_code == 2 and "margin_floor_m" in out.output and "Traceback" not in out.output
