"""The operator console in headless Chromium against the fake API: token, jobs, plan, survey, actions, live updates."""

from __future__ import annotations

from playwright.sync_api import expect

from .conftest import screenshot
from .ui import click_and_confirm, login, open_job, use_token

APPROVER = "approver-token-bob"
OPERATOR = "operator-token-carol"
PLANNER = "planner-token-alice"
TIMEOUT_MS = 10_000


def test_without_token_the_page_asks_for_one(page, fake_server):
    url, _ = fake_server
    page.goto(url + "/")
    expect(page.locator("#banner")).to_contain_text("Enter a bearer token")
    expect(page.locator("#health")).to_contain_text("ok")
    use_token(page, "wrong-token-123")
    expect(page.locator("#banner")).to_contain_text("401")
    assert page.js_errors == []


def test_plan_details_are_drawn(page, fake_server):
    url, store = fake_server
    login(page, url, APPROVER)
    expect(page.locator("#jobs tbody tr")).to_have_count(2, timeout=TIMEOUT_MS)
    open_job(page, store.plan_id)
    expect(page.locator("#job-state")).to_have_text("planned")
    # CoM trace over the support polygon with the threshold drawn
    expect(page.locator('#com-chart polygon[data-role="support"]')).to_have_count(1)
    expect(page.locator('#com-chart polygon[data-role="threshold"]')).to_have_count(1)
    expect(page.locator('#com-chart polyline[data-role="com-trace"]')).to_have_count(1)
    points = page.locator('#com-chart polyline[data-role="com-trace"]').get_attribute("points")
    assert len(points.split()) == 400
    # margins over time with the threshold line and segment bands
    expect(page.locator('#margin-chart polyline[data-role="margin-line"]')).to_have_count(1)
    expect(page.locator('#margin-chart line[data-role="threshold-line"]')).to_have_count(1)
    expect(page.locator("#margin-chart rect[data-segment]")).to_have_count(3)
    expect(page.locator("#segments tbody tr")).to_have_count(3)
    expect(page.locator("#plan-summary")).to_contain_text("min margin 80.0 mm")
    # the threshold polygon is the support polygon shrunk by 60 mm (checked in the page's own code)
    inner = page.evaluate("regraspConsole.shrinkConvex([[1,1],[-1,1],[-1,-1],[1,-1]], 0.25)")
    assert sorted(tuple(round(abs(v), 9) for v in p) for p in inner) == [(0.75, 0.75)] * 4
    expect(page.locator("#btn-approve")).to_be_visible()
    expect(page.locator("#btn-dispatch")).to_be_hidden()
    shot = screenshot(page, "console-plan")
    assert shot.stat().st_size > 10_000
    assert page.js_errors == []


def test_survey_table_and_chart(page, fake_server):
    url, store = fake_server
    login(page, url, PLANNER)
    survey_id = next(j for j in store.jobs.values() if j["kind"] == "survey")["id"]
    open_job(page, survey_id)
    rows = page.locator("#survey-table tbody tr")
    expect(rows).to_have_count(4)
    expect(page.locator('#survey-table tr[data-hands="left-left"]')).to_contain_text("recommended")
    expect(page.locator('#survey-table tr[data-hands="left-left"]')).to_contain_text("0.9986")
    expect(page.locator('#survey-table tr[data-hands="right-left"]')).to_contain_text("no feasible handover")
    expect(page.locator("#survey-chart rect.bar")).to_have_count(4)
    expect(page.locator('#survey-chart rect.bar-recommended[data-hands="left-left"]')).to_have_count(1)
    # The uncertainty, as the CLI shows it: intervals, seeds, the tie and the recommendation.
    left = page.locator('#survey-table tr[data-hands="left-left"]')
    expect(left.locator('[data-role="ci"]')).to_have_text("[0.9961, 1.0000]")
    expect(left.locator('[data-role="seeds"]')).to_have_text("12")
    expect(left).to_contain_text("recommended (tie)")
    expect(page.locator('#survey-table tr[data-hands="right-right"]')).to_contain_text("tie with left-left")
    summary = page.locator("#survey-summary")
    expect(summary).to_contain_text("Recommended: left-left")
    expect(summary).to_contain_text("95 % interval [0.9961, 1.0000], 12 seeds")
    expect(summary).to_contain_text("a tie with right-right")
    expect(page.locator('#survey-chart [data-role="ci-bar"]')).to_have_count(3)
    # One colour per hand configuration, the CLI's (experiments/plots.py HANDS_COLOURS: tab:blue, tab:orange, ...).
    assert "#1f77b4" in page.locator('#survey-chart rect.bar[data-hands="left-left"]').get_attribute("style")
    assert "#ff7f0e" in page.locator('#survey-chart rect.bar[data-hands="right-right"]').get_attribute("style")
    screenshot(page, "console-survey")
    assert page.js_errors == []


def test_without_v1_me_buttons_follow_the_state_and_a_refusal_shows_its_403(page, fake_server):
    """A service without GET /v1/me: the page cannot tell the roles, so the API's 403 explains."""
    url, store = fake_server
    store.me_enabled = False
    login(page, url, PLANNER)
    open_job(page, store.plan_id)
    click_and_confirm(page, "approve")
    expect(page.locator("#problem")).to_contain_text("403")
    expect(page.locator("#problem")).to_contain_text("needs the role 'approver'")
    expect(page.locator("#job-state")).to_have_text("planned")


def test_approve_then_dispatch_and_the_state_changes_live(page, fake_server):
    url, store = fake_server
    login(page, url, APPROVER)
    open_job(page, store.plan_id)
    click_and_confirm(page, "approve")
    expect(page.locator("#job-state")).to_have_text("approved", timeout=TIMEOUT_MS)
    expect(page.locator("#job-approval")).to_contain_text("bob")
    # the approver (no operator role) is not offered dispatch
    expect(page.locator("#btn-dispatch")).to_be_hidden()
    # the operator dispatches; execution progress arrives over SSE
    use_token(page, OPERATOR)
    open_job(page, store.plan_id)
    click_and_confirm(page, "dispatch")
    expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
    expect(page.locator("#live-mode")).to_have_text("SSE")
    expect(page.locator("#btn-stop")).to_be_visible()
    expect(page.locator("#job-state")).to_have_text("succeeded", timeout=TIMEOUT_MS)
    expect(page.locator(f'#jobs tbody tr[data-job-id="{store.plan_id}"]')).to_have_attribute(
        "data-state", "succeeded", timeout=TIMEOUT_MS)
    expect(page.locator("#job-progress-bar")).to_have_attribute("style", "width: 100%;")
    screenshot(page, "console-after-execution")
    assert page.js_errors == []


def test_token_is_kept_in_session_storage_only(page, fake_server):
    url, _ = fake_server
    login(page, url, APPROVER)
    expect(page.locator("#jobs tbody tr")).to_have_count(2, timeout=TIMEOUT_MS)
    assert page.evaluate("sessionStorage.getItem('regrasp.token')") == APPROVER
    assert page.evaluate("localStorage.length") == 0
    page.reload()
    expect(page.locator("#jobs tbody tr")).to_have_count(2, timeout=TIMEOUT_MS)
    page.click("#token-clear")
    assert page.evaluate("sessionStorage.getItem('regrasp.token')") is None


def test_without_sse_the_page_polls_and_still_follows_the_job(page, fake_server):
    url, store = fake_server
    store.sse_enabled = False
    store.approve(store.plan_id)
    login(page, url, OPERATOR)
    open_job(page, store.plan_id)
    click_and_confirm(page, "dispatch")
    expect(page.locator("#live-mode")).to_have_text("polling every 500 ms", timeout=TIMEOUT_MS)
    expect(page.locator("#job-state")).to_have_text("succeeded", timeout=TIMEOUT_MS)
    assert page.js_errors == []


def test_planner_submits_a_job_from_the_form(page, fake_server):
    url, store = fake_server
    login(page, url, PLANNER)
    expect(page.locator("#jobs tbody tr")).to_have_count(2, timeout=TIMEOUT_MS)
    page.click("#submit-box summary")
    page.select_option("#submit-scenario", "staggered")
    page.fill("#submit-threshold", "40")
    page.click("#submit-form button[type=submit]")
    expect(page.locator("#jobs tbody tr")).to_have_count(3, timeout=TIMEOUT_MS)
    expect(page.locator("#job-state")).to_have_text("planned", timeout=TIMEOUT_MS)
    new = [j for j in store.jobs.values() if j["request"].get("scenario") == "staggered"]
    assert len(new) == 1 and new[0]["request"]["threshold_m"] == 0.04
    expect(page.locator('#com-chart polyline[data-role="com-trace"]')).to_have_count(1)


def test_a_failed_plan_shows_its_failure_and_no_empty_charts(page, fake_server):
    """A plan that found no motion: its failure first, no empty charts, no "headroom - mm"."""
    from .fake_api import synthetic_plan

    url, store = fake_server
    plan = synthetic_plan()
    plan.update(status="failed", trajectory=[], segments=[], min_margin_m=None,
                failure={"code": "THRESHOLD_TOO_LARGE", "message": "a 200 mm threshold leaves no point of the "
                                                                   "support polygon for the CoM"})
    with store.lock:
        job = store._new("plan", "alice", state="failed", result=plan, progress=1.0)
        job["error"] = {"code": "THRESHOLD_TOO_LARGE", "message": plan["failure"]["message"]}
    login(page, url, PLANNER)
    open_job(page, job["id"])
    box = page.locator("#failure-box")
    expect(box).to_be_visible()
    expect(box).to_contain_text("THRESHOLD_TOO_LARGE")
    expect(box).to_have_attribute("data-code", "THRESHOLD_TOO_LARGE")
    for chart in ("#margin-chart", "#com-chart"):
        expect(page.locator(chart)).to_be_hidden()
    expect(page.locator("#segments")).to_be_hidden()
    expect(page.locator("#plan-summary")).to_contain_text("no motion was planned")
    assert "headroom - mm" not in (page.locator("#detail-body").text_content() or "")
    assert page.js_errors == []


def test_a_hands_auto_plan_shows_the_survey_recommendation_with_interval_seeds_and_ties(page, fake_server):
    """stats.survey_recommendation (as planner.survey.auto writes it for hands: auto) is shown with the
    recommended row's interval and seeds and each tied row's; a plan that named its hands shows none."""
    from planner.survey.auto import survey_summary

    from .fake_api import synthetic_survey

    url, store = fake_server
    auto = store.add("plan", "alice", state="planned")
    auto["result"]["stats"]["survey_recommendation"] = survey_summary(synthetic_survey())
    login(page, url, APPROVER)
    open_job(page, store.plan_id)
    expect(page.locator("#plan-summary")).to_contain_text("min margin")
    expect(page.locator("#plan-survey")).to_be_hidden()
    open_job(page, auto["id"])
    said = page.locator("#plan-survey")
    expect(said).to_be_visible()
    expect(said).to_contain_text("left-left R = 0.999 [0.996, 1.000] over 12 seeds")
    expect(said).to_contain_text("a tie (overlapping 95 % intervals) with right-right R = 0.992 [0.984, 0.998] over 12 seeds")
    expect(said).to_have_attribute("data-tie", "true")
    assert page.js_errors == []
