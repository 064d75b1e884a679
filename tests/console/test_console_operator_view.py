"""The operator's view on the real service, the real planner and the simulated controller.

A `regrasp serve` process (SQLite, worker process, zenoh bridge) plans a small real task; the
page draws the robot from its URDF in 3D, links the margin chart, the segment table and the 3D
pose, shows the gate's dry run as a risk card, asks before approving and dispatching, follows
the controller's index during execution and stops it from the always-visible Stop button.
"""

from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Any, Iterator

import httpx
import pytest
import yaml
from playwright.sync_api import expect

from planner.jobs.request_names import registered_scenarios
from tests.service.conftest import TOKEN as SERVICE_TOKENS
from tests.service.conftest import (
    Server,
    free_port,
    start_controller_sim,
    stop_process,
    wait_controller_alive,
    wait_state,
)

from .conftest import screenshot
from .ui import confirm, login, open_job

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = yaml.safe_load((ROOT / "tests" / "data" / "small-box.yaml").read_text())
REQUEST = {"scenario": SCENARIO, "seed": 1, "time_limit_s": 300}
#: Planning the small box takes seconds; the first job of a fresh worker also loads the robot model.
PLAN_TIMEOUT_S = 400
TIMEOUT_MS = 30_000
#: The robot covers at least this many pixels of the 3D canvas (it fills a good part of it).
MIN_ROBOT_PIXELS = 3000
#: Largest difference between the CoM the page computes from the URDF and the plan's, m.
COM_TOLERANCE_M = 0.002
ALICE, BOB, CAROL = SERVICE_TOKENS["alice"], SERVICE_TOKENS["bob"], SERVICE_TOKENS["carol"]  # planner; approver+operator; approver


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """The real service with the planner's handlers, a simulated controller, and one planned job."""
    from service.settings import DEFAULT_HANDLERS

    data = tmp_path_factory.mktemp("operator-view")
    port = free_port()
    srv = Server(data, workers=1, handlers=DEFAULT_HANDLERS, check_scenario_names="true", bridge_port=port).start()
    sim = start_controller_sim(data, port, speed=1)
    try:
        with srv.client("alice") as alice:
            job = alice.post("/v1/jobs", json={"kind": "plan", "request": REQUEST}).json()
            planned = wait_state(alice, job["id"], {"planned", "failed"}, PLAN_TIMEOUT_S)
            assert planned["state"] == "planned", planned["error"]
        yield {"srv": srv, "sim": sim, "url": srv.url, "job": planned}
    finally:
        stop_process(sim)
        srv.stop()


def _new_planned(srv: Server, request: dict[str, Any] | None = None) -> dict[str, Any]:
    with srv.client("alice") as alice:
        job = alice.post("/v1/jobs", json={"kind": "plan", "request": request or REQUEST}).json()
        done = wait_state(alice, job["id"], {"planned", "failed"}, PLAN_TIMEOUT_S)
    assert done["state"] == "planned", done["error"]
    return done


def _open(page, url: str, token: str, job_id: str) -> None:
    login(page, url, token)
    open_job(page, job_id, timeout_ms=TIMEOUT_MS)
    expect(page.locator("#view3d")).to_have_attribute("data-status", "drawn", timeout=TIMEOUT_MS)


def _canvas_pixels(page) -> Any:
    import numpy as np
    from PIL import Image

    png = page.locator('#view3d canvas').screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def test_the_3d_view_draws_the_robot_where_its_urdf_puts_it(page, live):
    job = live["job"]
    _open(page, live["url"], BOB, job["id"])
    with_robot = _canvas_pixels(page)
    page.evaluate("window.regrasp3d.setRobotVisible(false)")
    without = _canvas_pixels(page)
    page.evaluate("window.regrasp3d.setRobotVisible(true)")
    changed = (abs(with_robot - without).sum(axis=2) > 30).sum()
    assert changed > MIN_ROBOT_PIXELS, f"the robot covers only {changed} pixels of the canvas"
    # The pose drawn is the plan's: the CoM recomputed in the page from the URDF's inertials at the
    # drawn joints (with the held object) is the plan's CoM.
    traj = job["result"]["trajectory"]
    for i in (0, len(traj) // 3, len(traj) // 2, len(traj) - 1):
        com = page.evaluate(f"window.regrasp3d.comAt({i})")
        assert max(abs(a - b) for a, b in zip(com, traj[i]["com"])) < COM_TOLERANCE_M, (i, com, traj[i]["com"])
    screenshot(page, "operator-view-3d")
    assert page.js_errors == []


def test_hovering_the_margin_chart_moves_the_3d_pose_and_highlights_the_segment(page, live):
    job = live["job"]
    plan = job["result"]
    _open(page, live["url"], BOB, job["id"])
    overlay = page.locator('#margin-chart rect[data-role="hover"]')
    overlay.scroll_into_view_if_needed()
    box = overlay.bounding_box()
    seen = []
    for fraction in (0.15, 0.6):
        page.mouse.move(box["x"] + box["width"] * fraction, box["y"] + box["height"] / 2)
        readout = page.locator("#cursor-readout")
        expect(readout).not_to_have_attribute("data-index", str(seen[-1][0]) if seen else "-1")
        index = int(readout.get_attribute("data-index"))
        assert page.evaluate("window.regrasp3d.index()") == index
        segment = next(k for k, s in enumerate(plan["segments"]) if s["first"] <= index <= s["last"])
        expect(page.locator("#segments tbody tr.active")).to_have_attribute("data-segment", str(segment))
        seen.append((index, page.evaluate("window.regrasp3d.linkPosition('r_tcp')")))
    (i0, hand0), (i1, hand1) = seen
    assert abs(i1 / len(plan["trajectory"]) - 0.6) < 0.05 and abs(i0 / len(plan["trajectory"]) - 0.15) < 0.05
    assert max(abs(a - b) for a, b in zip(hand0, hand1)) > 0.02, "the right hand did not move between the moments"
    # The other way: hovering a segment row moves the chart's cursor and the 3D pose to its worst moment.
    row = page.locator('#segments tbody tr[data-segment="3"]')
    row.hover()
    worst = int(row.get_attribute("data-worst"))
    expect(page.locator("#margin-chart svg")).to_have_attribute("data-cursor", str(worst))
    assert page.evaluate("window.regrasp3d.index()") == worst
    # The timeline scrubs every view.
    page.locator("#timeline").fill("100")
    expect(page.locator("#cursor-readout")).to_have_attribute("data-index", "100")
    assert page.evaluate("window.regrasp3d.index()") == 100
    screenshot(page, "operator-view-linked")
    assert page.js_errors == []


def test_the_risk_card_shows_the_gates_worst_sample(page, live):
    from robot_bridge.gate import SafetyGate

    job = live["job"]
    plan = job["result"]
    verdict = SafetyGate().check(plan, offline=True)  # the gate's own figures, recomputed here
    per_point = verdict.stats["time"]["samples_per_point"]
    worst = verdict.stats["com_margin"]
    point = worst["at_sample"] // per_point
    headroom_mm = (worst["min_margin_m"] - plan["threshold_m"]) * 1000
    _open(page, live["url"], BOB, job["id"])
    card = page.locator("#risk-card")
    expect(card).to_be_visible(timeout=TIMEOUT_MS)
    expect(page.locator("#risk-verdict")).to_have_attribute("data-passed", "true")
    cell = page.locator('[data-role="risk-worst"]')
    expect(cell).to_have_attribute("data-point", str(point))
    expect(cell).to_contain_text(f"headroom {headroom_mm:.1f} mm")
    expect(cell).to_contain_text(f"{worst['min_margin_m'] * 1000:.1f} mm")
    segment = next(k for k, s in enumerate(plan["segments"]) if s["first"] <= point <= s["last"])
    expect(cell).to_contain_text(f"segment {segment} {plan['segments'][segment]['kind']}")
    page.click('[data-role="risk-goto"]')
    expect(page.locator("#cursor-readout")).to_have_attribute("data-index", str(point))
    screenshot(page, "operator-view-risk-card")
    assert page.js_errors == []


def test_approve_and_dispatch_ask_first_showing_the_plan_hash(page, live):
    job = _new_planned(live["srv"])
    sha = job["plan_sha256"]
    _open(page, live["url"], CAROL, job["id"])
    page.click("#btn-approve")
    expect(page.locator("#confirm-hash")).to_have_text(sha[:12])
    screenshot(page, "operator-view-confirm")
    page.click("#confirm-cancel")  # declined: nothing is sent
    expect(page.locator("#confirm")).to_be_hidden()
    with httpx.Client(base_url=live["url"], headers={"Authorization": f"Bearer {CAROL}"}) as carol:
        assert carol.get(f"/v1/jobs/{job['id']}").json()["state"] == "planned"
    page.click("#btn-approve")
    confirm(page, "approve", sha)
    expect(page.locator("#job-state")).to_have_text("approved", timeout=TIMEOUT_MS)
    screenshot(page, "operator-view-approved")
    assert page.js_errors == []


def test_a_stop_clicked_during_execution_aborts_the_job(page, live):
    srv, sim = live["srv"], live["sim"]
    job = _new_planned(srv)
    with srv.client("carol") as carol:
        r = carol.post(f"/v1/jobs/{job['id']}/approve", json={"plan_sha256": job["plan_sha256"]})
        assert r.status_code == 200, r.text
    wait_controller_alive(srv, sim, 60)
    _open(page, live["url"], BOB, job["id"])
    page.click("#btn-dispatch")
    expect(page.locator("#confirm-hash")).to_have_text(job["plan_sha256"][:12])
    page.click("#confirm-ok")
    expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
    stop = page.locator("#btn-stop")
    expect(stop).to_be_visible()
    expect(stop).to_be_in_viewport()
    # The controller's index moves the execution cursor; the message says what happens.
    chart = page.locator("#margin-chart svg")
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and int(chart.get_attribute("data-exec-index") or 0) <= 0:
        time.sleep(0.1)
    index = int(chart.get_attribute("data-exec-index") or 0)
    assert index > 0, "no execution cursor"
    expect(page.locator("#job-message")).to_contain_text("robot moving: point")
    assert "robot_state" not in (page.locator("#job-message").text_content() or "")
    page.evaluate("window.scrollTo(0, document.body.scrollHeight)")  # far from the job's buttons: Stop stays on screen
    expect(stop).to_be_in_viewport()
    screenshot(page, "operator-view-executing")
    stop.click()
    expect(page.locator("#job-state")).to_have_text("aborted", timeout=TIMEOUT_MS)
    expect(stop).to_be_hidden()
    with srv.client("bob") as bob:
        done = bob.get(f"/v1/jobs/{job['id']}").json()
        assert done["state"] == "aborted" and done["error"]["code"] == "ABORTED"
        history = bob.get(f"/v1/jobs/{job['id']}/events", params={"follow": "false"}).text
        assert "stop requested by bob" in history and '"event":"stop_sent"' in history
    # It ended early: the controller's last index is well short of the plan's end.
    assert index < len(job["result"]["trajectory"]) - 1
    # The executed margin, computed in the page from the measured joints, was drawn against the planned one.
    assert page.locator('#margin-chart polyline[data-role="exec-run"]').first.get_attribute("points")
    assert page.js_errors == []


def test_the_submit_form_lists_the_services_names_and_keeps_the_scenarios_values(page, live):
    login(page, live["url"], ALICE)
    page.click("#submit-box summary")
    expect(page.locator("#submit-scenario option")).to_have_count(len(registered_scenarios()), timeout=TIMEOUT_MS)
    assert sorted(page.locator("#submit-scenario option").all_inner_texts()) == sorted(registered_scenarios())
    assert page.locator("#submit-hands option").all_inner_texts()[1:] == ["auto", "left-left", "right-right", "left-right",
                                                                           "right-left"]
    page.select_option("#submit-scenario", "staggered")
    expect(page.locator("#submit-defaults")).to_contain_text("threshold 30 mm")
    assert page.locator("#submit-threshold").input_value() == "" and page.locator("#submit-seed").input_value() == ""
    page.select_option("#submit-kind", "survey")
    page.fill("#submit-time-limit", "5")
    with httpx.Client(base_url=live["url"], headers={"Authorization": f"Bearer {ALICE}"}) as alice:
        before = {j["id"] for j in alice.get("/v1/jobs").json()["jobs"]}
        page.click("#submit-form button[type=submit]")
        deadline = time.monotonic() + 20
        new = []
        while time.monotonic() < deadline and not new:
            new = [j for j in alice.get("/v1/jobs").json()["jobs"] if j["id"] not in before]
            time.sleep(0.2)
        assert new and new[0]["request"] == {"scenario": "staggered", "time_limit_s": 5}
        alice.post(f"/v1/jobs/{new[0]['id']}/cancel")
    # A refused submission shows its error in the form, and no job panel.
    login(page, live["url"], ALICE)
    page.click("#submit-box summary")
    expect(page.locator("#submit-scenario option")).to_have_count(len(registered_scenarios()), timeout=TIMEOUT_MS)
    page.fill("#submit-seed", str(2**64))
    page.click("#submit-form button[type=submit]")
    expect(page.locator("#submit-problem")).to_contain_text("422")
    expect(page.locator("#detail-body")).to_be_hidden()
    assert page.js_errors == []


def test_the_risk_card_compares_with_the_same_task_planned_at_0_mm(page, live):
    job = live["job"]
    login(page, live["url"], ALICE)
    open_job(page, job["id"], timeout_ms=TIMEOUT_MS)
    button = page.locator('[data-role="plan-unconstrained"]')
    expect(button).to_be_visible(timeout=TIMEOUT_MS)
    with live["srv"].client("alice") as alice:
        before = {j["id"] for j in alice.get("/v1/jobs").json()["jobs"]}
        button.click()
        expect(page.locator("#risk-facts")).to_contain_text("submitted as job", timeout=TIMEOUT_MS)
        new = [j for j in alice.get("/v1/jobs").json()["jobs"] if j["id"] not in before]
        assert len(new) == 1 and new[0]["request"] == {**job["request"], "threshold_m": 0}
        free = wait_state(alice, new[0]["id"], {"planned", "succeeded", "failed"}, PLAN_TIMEOUT_S)
    # Planned below the site's floor: a comparison, which ends succeeded and never reaches the robot.
    assert free["state"] == "succeeded" and free["comparison"] is True, (free["state"], free["error"])
    page.reload()
    open_job(page, job["id"], timeout_ms=TIMEOUT_MS)
    facts = page.locator("#risk-facts")
    free_min = free["result"]["min_margin_m"] * 1000
    expect(facts).to_contain_text(f"the unconstrained plan (job {free['id'][:8]}) reaches {free_min:.1f} mm", timeout=TIMEOUT_MS)
    breaks = free["result"]["min_margin_m"] < job["result"]["threshold_m"] - 1e-4
    expect(facts).to_contain_text("below the threshold" if breaks else "within the threshold")
    assert page.js_errors == []
