"""What every robot's tests make and check of a plan and a survey: a built-in task planned, the gate passing the
plan with the planner's own largest effort ratio, and a small survey of a built-in task with its rows."""

from __future__ import annotations

import pytest


def builtin_plan(scenario: str, hands: str) -> dict:
    """The plan of the built-in ``scenario`` with ``hands``, with the planner's default settings."""
    from planner.jobs.plan_job import PlanOptions, plan_scenario
    from planner.scene.scenarios import load_builtin

    return plan_scenario(load_builtin(scenario), PlanOptions(hands=hands))


def assert_the_gate_passes(plan: dict) -> None:
    """The safety gate (its own kinematics and limits) passes ``plan`` and finds the plan's largest effort ratio.

    Judged at the plan's own threshold (a policy without a floor): these robots' tasks are planned at 20 mm."""
    from robot_bridge.gate import SafetyGate
    from schemas.policy import SafetyPolicy

    verdict = SafetyGate(policy=SafetyPolicy(margin_floor_m=0.0)).check(plan, offline=True)
    assert verdict.passed, verdict.message
    assert verdict.stats["effort"]["max_ratio"] == pytest.approx(max(p["effort_ratio"] for p in plan["trajectory"]),
                                                                  abs=1e-9)


def small_survey(scenario: str) -> tuple[dict, dict]:
    """A survey of the built-in ``scenario``, two seeds of 100 states, each on its own key path (a pool of two):
    (the document, its rows by hands)."""
    from planner.scene.scenarios import load_builtin
    from planner.survey.estimator import Estimator
    from planner.survey.runner import run_survey

    est = Estimator(until="states", states_per_seed=100, seeds_min=2, seeds_max=2, key_path_pool=2)
    doc, _ = run_survey(load_builtin(scenario), estimator=est, workers=1, keep_states=False)
    return doc, {r["hands"]: r for r in doc["rows"]}
