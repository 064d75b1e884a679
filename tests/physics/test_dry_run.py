"""The physics dry run on the risk card, and the safety policy's check of it at dispatch."""

from __future__ import annotations

import json

from schemas.plan import plan_sha256
from schemas.policy import SafetyPolicy
from service.execution.physics_gate import physics_problem
from service.jobs.risk import physics_dry_run, risk_card

from .test_twin import arm_plan


def test_the_risk_card_carries_the_dry_run_bound_to_the_plan():
    plan = json.loads(arm_plan())
    card = risk_card(plan)
    phys = card["physics"]
    assert phys["stood"] is True
    assert phys["report"]["plan_sha256"] == card["plan_sha256"] == plan_sha256(plan)
    assert phys["report"]["speed"] == 1.0 and phys["report"]["mass_scale"] == 1.0
    assert phys["at"]["t"] == phys["report"]["min_cop_margin_at_s"]
    assert phys["at"]["segment"]["kind"] == "transit"  # the arm plan has one segment


def test_the_policy_refuses_a_dry_run_that_fell_or_kept_too_little_margin_and_passes_one_that_stood():
    plan = json.loads(arm_plan())
    sha = plan_sha256(plan)
    card = {"plan_sha256": sha, "physics": physics_dry_run(plan)}
    margin = card["physics"]["report"]["min_cop_margin_m"]
    required = SafetyPolicy(require_physics_pass=True)
    assert physics_problem(SafetyPolicy(), None, sha) is None  # the built-in policy does not ask
    assert physics_problem(required, card, sha) is None
    assert physics_problem(SafetyPolicy(require_physics_pass=True, min_cop_margin_m=margin - 0.001), card, sha) is None
    high = physics_problem(SafetyPolicy(require_physics_pass=True, min_cop_margin_m=margin + 0.001), card, sha)
    assert high is not None and "min_cop_margin_m" in high
    assert "none" in physics_problem(required, None, sha)
    assert "not this plan's" in physics_problem(required, card, "0" * 64)
    heavy = json.loads(arm_plan())
    heavy["object"]["mass_kg"] *= 6  # planned light, carried heavy: the twin does not stand
    heavy_card = {"plan_sha256": plan_sha256(heavy), "physics": physics_dry_run(heavy)}
    problem = physics_problem(required, heavy_card, plan_sha256(heavy))
    assert problem is not None and ("fell" in problem or "faulted" in problem)
    broken = {"plan_sha256": sha, "physics": {"error": "the physics dry run could not be made: boom"}}
    assert "failed" in physics_problem(required, broken, sha)
