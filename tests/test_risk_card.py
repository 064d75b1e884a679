"""The risk card: the safety gate's dry run of a real plan, its worst moments, and the API's report.

The plan is the small-box task planned for real; the card's figures are checked against the
gate run here and against the plan's own segments; a changed plan is vetoed with the point and
segment that fail; the API serves the card stored with the job, the gate's verdict at dispatch
and the comparison with the same task planned at 0 mm.
"""

from __future__ import annotations

import copy
from pathlib import Path

import httpx
import pytest
import yaml

from robot_bridge.gate import SafetyGate
from schemas.plan import canonical_json
from service.jobs.risk import compare_with_unconstrained, risk_card, safe_risk_card

ROOT = Path(__file__).resolve().parent
SCENARIO = yaml.safe_load((ROOT / "data" / "small-box.yaml").read_text())


class _Ctx:
    def progress(self, fraction: float, message: str) -> None:
        pass

    def cancelled(self) -> bool:
        return False


@pytest.fixture(scope="module")
def plans() -> dict[str, dict]:
    from planner.jobs.entry import run_plan

    return {"constrained": run_plan({"scenario": SCENARIO}, _Ctx()),
            "free": run_plan({"scenario": SCENARIO, "threshold_m": 0.0}, _Ctx())}


def test_the_card_reports_the_gates_worst_moments(plans):
    plan = plans["constrained"]
    card = risk_card(plan, canonical_json(plan))
    verdict = SafetyGate().check(plan, offline=True)
    per_point = verdict.stats["time"]["samples_per_point"]
    assert card["gate"]["passed"] is True and card["gate"]["failed_at"] is None
    assert card["plan_sha256"] == verdict.plan_sha256
    assert card["margin_floor_m"] == SafetyGate().policy.margin_floor_m  # the floor the console measures against
    com = card["com_margin"]
    assert com["min_margin_m"] == verdict.stats["com_margin"]["min_margin_m"]
    assert com["headroom_m"] == pytest.approx(com["min_margin_m"] - plan["threshold_m"])
    assert com["point"] == verdict.stats["com_margin"]["at_sample"] // per_point
    assert com["t"] == pytest.approx(verdict.stats["com_margin"]["at_sample"] * plan["dt_s"] / per_point)
    seg = plan["segments"][com["segment"]["index"]]
    assert seg["first"] <= com["point"] <= seg["last"] and com["segment"]["kind"] == seg["kind"]
    assert com["hand"] == plan["trajectory"][com["point"]]["holding"]
    # the gate's margin is its own (URDF kinematics): close to, not copied from, the planner's
    assert abs(com["min_margin_m"] - plan["min_margin_m"]) < 2e-3
    assert card["zmp"]["min_margin_m"] == verdict.stats["zmp"]["min_margin_m"]


def test_effort_headroom_comes_from_the_plan_where_it_has_limits(plans):
    plan = copy.deepcopy(plans["constrained"])
    card = risk_card(plan)
    ratios = [p.get("effort_ratio") for p in plan["trajectory"]]
    if any(isinstance(r, float) for r in ratios):
        peak = max(r for r in ratios if isinstance(r, float))
        assert card["effort"]["max_ratio"] == peak and card["effort"]["headroom"] == pytest.approx(1 - peak)
    for p in plan["trajectory"]:
        p.pop("effort_ratio", None)
    assert risk_card(plan)["effort"] is None  # no limits in the plan: nothing claimed


def test_a_changed_plan_is_vetoed_with_the_point_and_segment_that_fail(plans):
    plan = copy.deepcopy(plans["constrained"])
    seg = plan["segments"][3]
    bad = (seg["first"] + seg["last"]) // 2
    plan["trajectory"][bad]["q"][0] = 10.0  # far outside the joint's limits
    card = risk_card(plan)
    assert card["gate"]["passed"] is False and card["gate"]["check"] == "joint_position"
    assert card["gate"]["failed_at"]["point"] == bad
    assert card["gate"]["failed_at"]["segment"]["index"] == 3


def test_a_card_that_cannot_be_made_says_why():
    card = safe_risk_card({"schema": "regrasp.plan/1", "robot": {"name": "no-such-robot"}})
    assert "error" in card or card["gate"]["passed"] is False


def test_the_comparison_with_the_0_mm_plan(plans):
    cmp = compare_with_unconstrained(plans["constrained"], plans["free"])
    assert cmp["unconstrained_min_margin_m"] == plans["free"]["min_margin_m"]
    assert cmp["unconstrained_breaks_threshold"] == (plans["free"]["min_margin_m"] < plans["constrained"]["threshold_m"] - 1e-4)
    qs = [[p["q"] for p in plans[k]["trajectory"]] for k in ("constrained", "free")]
    assert cmp["plans_differ"] == (qs[0] != qs[1])
    assert compare_with_unconstrained(plans["constrained"], plans["constrained"])["plans_differ"] is False


def test_the_api_serves_the_stored_card_the_dispatch_verdict_and_the_0_mm_comparison(plans, tmp_path):
    from service.app import create_app
    from service.execution.bridge import NoBridge
    from service.jobs.results import package
    from service.settings import ServiceSettings
    from tests.console.conftest import serve

    token = "risk-test-token-bob"
    settings = ServiceSettings(data_dir=tmp_path, workers=1, tokens={token: {"user": "bob", "roles": ["approver"]}},
                               preload_robot=False, check_scenario_names=False)
    app = create_app(settings, run_workers=False, bridge=NoBridge())
    with serve(app) as url, httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=30) as c:
        store = app.state.service.store
        ids = {}
        for name, request in (("constrained", {"scenario": SCENARIO}), ("free", {"scenario": SCENARIO, "threshold_m": 0.0})):
            packed = package(plans[name])
            row, _ = store.create(job_id=f"job-{name}", kind="plan", submitter="alice", request=request,
                                  request_sha256=name, idempotency_key=None, provenance={}, queue_limit=100)
            store.claim("test-owner", 1, 60.0)
            store.finish_planning(row["id"], "test-owner", "planned", message="planned", planning_s=1.0,
                                  result_text=packed["text"], extra={"plan_sha256": packed["sha256"]},
                                  data={"plan_sha256": packed["sha256"]})
            ids[name] = row["id"]
        # No card was stored with these jobs: the first request makes it and stores it.
        first = c.get(f"/v1/jobs/{ids['constrained']}/risk")
        assert first.status_code == 200, first.text
        report = first.json()
        assert report["planning"]["gate"]["passed"] is True
        assert report["unconstrained"]["job_id"] == ids["free"]
        assert report["unconstrained"]["unconstrained_min_margin_m"] == plans["free"]["min_margin_m"]
        events = store.events_after(ids["constrained"], 0, 500)
        assert sum(1 for e in events if (e.get("data") or {}).get("risk")) == 1
        assert c.get(f"/v1/jobs/{ids['constrained']}/risk").json()["planning"] == report["planning"]
        assert sum(1 for e in store.events_after(ids["constrained"], 0, 500) if (e.get("data") or {}).get("risk")) == 1
        # The gate's verdict at dispatch, as the bridge reports it, with the segment of the failing point.
        seg = plans["constrained"]["segments"][2]
        veto = {"passed": False, "check": "com_margin", "message": "the CoM margin falls to 20.00 mm",
                "sample_index": seg["first"] * 2, "point_index": seg["first"], "t": seg["first"] * 0.005,
                "threshold_m": 0.06, "samples": 7697}
        store.add_event(ids["constrained"], "bridge", message="gate", data={"event": "gate", "payload": veto})
        dispatch = c.get(f"/v1/jobs/{ids['constrained']}/risk").json()["dispatch"]
        assert dispatch["passed"] is False and dispatch["check"] == "com_margin"
        assert dispatch["point_index"] == seg["first"] and dispatch["segment"]["index"] in (1, 2)
        assert c.get("/v1/jobs/no-such-job/risk").status_code == 404
