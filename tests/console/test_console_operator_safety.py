"""What the operator sees is what the robot will do: the real service, the real planner, the simulated controller.

- a rejection asks first and needs a reason, which the job keeps;
- after Stop the page shows the robot's measured pose beside the plan, the executed margin ends at the last
  measurement, "plan the way back" plans a recovery that is approved, gated and run, and the next plan runs;
- a comparison (a plan below the site's floor) is drawn beside the task's plan and offered for no approval,
  and the API refuses to approve or dispatch it.
"""

from __future__ import annotations

import json
import time
from typing import Any

import httpx
import pytest
from playwright.sync_api import expect

from tests.service.conftest import wait_controller_alive, wait_state

from .conftest import screenshot
from .test_console_operator_view import (  # noqa: F401 - `live` is the module's fixture here too
    ALICE,
    BOB,
    CAROL,
    PLAN_TIMEOUT_S,
    REQUEST,
    TIMEOUT_MS,
    _new_planned,
    _open,
    live,
)

END = {"succeeded", "failed", "aborted", "rejected", "canceled"}


def _history(client: httpx.Client, job_id: str) -> list[dict[str, Any]]:
    text = client.get(f"/v1/jobs/{job_id}/events", params={"follow": "false"}).text
    out = []
    for block in text.split("\n\n"):
        for line in block.splitlines():
            if line.startswith("data: "):
                out.append(json.loads(line[6:]))
    return out


def _measured_indices(client: httpx.Client, job_id: str) -> list[int]:
    out = []
    for ev in _history(client, job_id):
        data = ev.get("data") or {}
        if ev["kind"] == "bridge" and data.get("event") == "robot_state":
            payload = data.get("payload") or {}
            samples = payload.get("samples") or [payload]
            out += [s["index"] for s in samples if isinstance(s.get("index"), int)]
    return out


def _approve(srv, job: dict[str, Any], as_user: str = "carol") -> None:
    with srv.client(as_user) as c:
        r = c.post(f"/v1/jobs/{job['id']}/approve", json={"plan_sha256": job["plan_sha256"]})
        assert r.status_code == 200, r.text


def test_reject_asks_for_a_reason_and_the_job_keeps_it(page, live):
    srv = live["srv"]
    job = _new_planned(srv)
    _open(page, live["url"], CAROL, job["id"])
    page.click("#btn-reject")
    dialog = page.locator("#reject-dialog")
    expect(dialog).to_be_visible()
    page.click("#reject-ok")  # no reason: refused in the page, nothing sent
    expect(page.locator("#reject-hint")).to_be_visible()
    expect(dialog).to_be_visible()
    page.click("#reject-cancel")
    expect(dialog).to_be_hidden()
    with srv.client("carol") as carol:
        assert carol.get(f"/v1/jobs/{job['id']}").json()["state"] == "planned"
    page.click("#btn-reject")
    page.fill("#reject-reason", "the right hand passes too close to the table")
    screenshot(page, "operator-reject-reason")
    page.click("#reject-ok")
    expect(page.locator("#job-state")).to_have_text("rejected", timeout=TIMEOUT_MS)
    with srv.client("carol") as carol:
        done = carol.get(f"/v1/jobs/{job['id']}").json()
        assert "too close to the table" in done["error"]["message"] and "carol" in done["error"]["message"]
        state = [e for e in _history(carol, job["id"]) if e["kind"] == "state" and e["state"] == "rejected"]
        assert state and state[0]["data"]["reason"] == "the right hand passes too close to the table"
    assert page.js_errors == []


def test_after_stop_the_console_shows_the_robot_and_brings_it_home(page, live):
    srv, sim = live["srv"], live["sim"]
    job = _new_planned(srv)
    _approve(srv, job)
    wait_controller_alive(srv, sim, 60)
    _open(page, live["url"], BOB, job["id"])
    page.click("#btn-dispatch")
    page.click("#confirm-ok")
    expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
    chart = page.locator("#margin-chart svg")
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and int(chart.get_attribute("data-exec-index") or 0) < 40:
        time.sleep(0.1)
    expect(page.locator('#margin-chart [data-role="exec-cursor-label"]')).to_contain_text("robot, t =")
    page.click("#btn-stop")
    expect(page.locator("#job-state")).to_have_text("aborted", timeout=TIMEOUT_MS)

    # Where the robot is: its measured pose as a ghost beside the plan, and the way back offered.
    expect(page.locator("#recovery")).to_be_visible(timeout=TIMEOUT_MS)
    expect(page.locator("#view3d")).to_have_attribute("data-ghost", "measured", timeout=TIMEOUT_MS)
    assert page.evaluate("window.regrasp3d.ghostShown()")
    with srv.client("bob") as bob:
        measured = _measured_indices(bob, job["id"])
    assert measured, "the execution reported no measured state"
    last = measured[-1]
    expect(page.locator("#recovery")).to_have_attribute("data-measured-index", str(last), timeout=TIMEOUT_MS)

    # The executed chart: no point past the last measurement; the cursor says where the robot stopped.
    expect(chart).to_have_attribute("data-exec-last-index", str(max(measured)), timeout=TIMEOUT_MS)
    last_x = float(chart.get_attribute("data-exec-last-x"))
    xs = [float(p.split(",")[0]) for run in page.locator('#margin-chart [data-role="exec-run"]').all()
          for p in (run.get_attribute("points") or "").split()]
    assert xs and max(xs) <= last_x + 0.05, (max(xs), last_x)
    expect(page.locator('#margin-chart [data-role="exec-cursor-label"]')).to_contain_text("robot stopped")
    # The segment the stop cut short says so; its executed minimum sits beside the planned one of the same points.
    partial = page.locator('#segments td.exec-min[data-status="partial"]')
    if last < len(job["result"]["trajectory"]) - 1:
        expect(partial).to_have_count(1)
        expect(partial).to_contain_text("at the same")
    screenshot(page, "operator-after-stop")

    # Plan the way back: a recover job, approved by another person, gated and run.
    page.click("#btn-recover")
    expect(page.locator("#job-kind")).to_have_text("recover", timeout=TIMEOUT_MS)
    recover_id = page.locator("#job-id").text_content()
    with srv.client("bob") as bob:
        planned = wait_state(bob, recover_id, {"planned", "failed"}, PLAN_TIMEOUT_S)
    assert planned["state"] == "planned", planned["error"]
    assert planned["submitter"] == "bob"
    _approve(srv, planned)
    _open(page, live["url"], BOB, recover_id)
    expect(page.locator("#btn-dispatch")).to_be_visible(timeout=TIMEOUT_MS)
    page.click("#btn-dispatch")
    page.click("#confirm-ok")
    expect(page.locator("#job-state")).to_have_text("succeeded", timeout=60_000)

    # The next plan dispatches and runs.
    nxt = _new_planned(srv)
    _approve(srv, nxt)
    with srv.client("bob") as bob:
        r = bob.post(f"/v1/jobs/{nxt['id']}/dispatch")
        assert r.status_code == 202, r.text
        done = wait_state(bob, nxt["id"], END, 120)
    assert done["state"] == "succeeded", (done["message"], done["error"])
    assert page.js_errors == []


def _comparisons_exist(url: str) -> bool:
    doc = httpx.get(url + "/openapi.json", timeout=10).json()
    return "comparison" in doc["components"]["schemas"]["Job"]["properties"]


def test_a_comparison_is_drawn_beside_the_plan_and_never_offered_for_approval(page, live):
    srv = live["srv"]
    if not _comparisons_exist(live["url"]):
        pytest.skip("this service has no comparison jobs yet (CONTRACT 5: \"comparison\": true on the job)")
    job = live["job"]
    with srv.client("alice") as alice:
        r = alice.post("/v1/jobs", json={"kind": "plan", "request": {**REQUEST, "threshold_m": 0}})
        assert r.status_code == 202, r.text
        free = wait_state(alice, r.json()["id"], END | {"planned"}, PLAN_TIMEOUT_S)
    assert free["comparison"] is True and free["state"] == "succeeded", (free["state"], free["error"])
    with srv.client("carol") as carol, srv.client("bob") as bob:
        r = carol.post(f"/v1/jobs/{free['id']}/approve", json={"plan_sha256": free["plan_sha256"]})
        assert r.status_code == 409 and "comparison" in r.json()["detail"]
        r = bob.post(f"/v1/jobs/{free['id']}/dispatch")
        assert r.status_code == 409
    # Its own view: no Approve, no Dispatch, and a note that says what it is.
    _open(page, live["url"], CAROL, free["id"])
    expect(page.locator("#comparison-note")).to_be_visible(timeout=TIMEOUT_MS)
    expect(page.locator("#comparison-note")).to_contain_text("not for the robot")
    for button in ("#btn-approve", "#btn-dispatch", "#btn-reject"):
        expect(page.locator(button)).to_be_hidden()
    # The task's plan: the comparison drawn as a second trace on its charts.
    _open(page, live["url"], CAROL, job["id"])
    expect(page.locator("#margin-chart svg")).to_have_attribute("data-compare", "drawn", timeout=TIMEOUT_MS)
    expect(page.locator("#com-chart svg")).to_have_attribute("data-compare", "drawn", timeout=TIMEOUT_MS)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not page.evaluate("window.regrasp3d.comparisonShown()"):
        time.sleep(0.1)
    assert page.evaluate("window.regrasp3d.comparisonShown()"), "the comparison's CoM trace is not in the 3D view"
    screenshot(page, "operator-comparison")
    assert page.js_errors == []
