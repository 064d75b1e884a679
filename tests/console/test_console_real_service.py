"""End to end: the console on the real service (FastAPI app, SQLite job store, worker
processes, audit pump, real uvicorn) in headless Chromium. Approve, then dispatch, and the
state changes on screen; the job's audit file then verifies against its stored head.

The robot side is a scripted bridge (the service's ``Bridge`` interface) that plays a
short execution; the zenoh bridge and the simulated controller have their own tests.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any, Callable

import httpx
import pytest
from playwright.sync_api import expect

from .conftest import SCREENSHOT_DIR, screenshot, serve

pytest.importorskip("service.api", reason="the HTTP API (service.api) is not installed")

TOKENS = {
    "e2e-token-alice-planner": {"user": "alice", "roles": ["planner"]},
    "e2e-token-bob-approver": {"user": "bob", "roles": ["approver"]},
    "e2e-token-carol-operator": {"user": "carol", "roles": ["operator"]},
}
ALICE, BOB, CAROL = list(TOKENS)
TIMEOUT_MS = 20_000
WAIT_S = 60.0
EXEC_STEPS = 6
EXEC_STEP_S = 0.25


class ScriptedBridge:
    """A controller that is alive, passes the gate and plays a few segments."""

    def __init__(self) -> None:
        self.executed: list[str] = []

    def controller_alive(self) -> bool:
        return True

    def execute(self, plan: dict[str, Any], *, job_id: str, approved_sha256: str, approval_expires_at: Any,
                threshold_m: float, on_event: Callable[[str, dict[str, Any]], None],
                stop_event: threading.Event):
        from service.bridge import Outcome

        on_event("gate_verdict", {"passed": True, "threshold_m": threshold_m})
        for seq in range(EXEC_STEPS):
            if stop_event.wait(EXEC_STEP_S):
                return Outcome("aborted", "stopped by an operator")
            on_event("segment", {"seq": seq, "segment_index": seq, "segment_count": EXEC_STEPS})
        self.executed.append(job_id)
        return Outcome("succeeded", None, {"passed": True})

    def stop(self, job_id: str) -> None:
        return None

    def close(self) -> None:
        return None


def _wait(client: httpx.Client, job_id: str, states: set[str]) -> dict[str, Any]:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} never reached {states}; last {job['state']}")


@pytest.fixture()
def real_service(tmp_path: Path):
    from service.app import create_app
    from service.settings import ServiceSettings

    settings = ServiceSettings(
        data_dir=tmp_path, workers=1, tokens=TOKENS, check_scenario_names=False, preload_robot=False,
        handlers={"plan": "tests.console.console_handlers:run_plan",
                  "survey": "tests.console.console_handlers:run_survey"},
    )
    bridge = ScriptedBridge()
    app = create_app(settings, bridge=bridge)
    with serve(app) as url:
        yield url, bridge


def test_approve_then_dispatch_on_the_real_service(page, real_service, tmp_path):
    url, bridge = real_service
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {ALICE}"}, timeout=10) as alice:
        r = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "console-e2e", "seed": 3}})
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        _wait(alice, job_id, {"planned"})

        page.goto(url + "/")
        page.fill("#token", BOB)
        page.click("#token-save")
        page.click(f'#jobs tbody tr[data-job-id="{job_id}"]', timeout=TIMEOUT_MS)
        expect(page.locator("#job-state")).to_have_text("planned", timeout=TIMEOUT_MS)
        expect(page.locator('#com-chart polyline[data-role="com-trace"]')).to_have_count(1)
        page.click("#btn-approve")
        expect(page.locator("#job-state")).to_have_text("approved", timeout=TIMEOUT_MS)
        expect(page.locator("#job-approval")).to_contain_text("bob")

        page.fill("#token", CAROL)
        page.click("#token-save")
        expect(page.locator("#btn-dispatch")).to_be_visible(timeout=TIMEOUT_MS)
        page.click("#btn-dispatch")
        expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
        expect(page.locator("#live-mode")).to_have_text("SSE")
        expect(page.locator("#job-state")).to_have_text("succeeded", timeout=TIMEOUT_MS)
        expect(page.locator(f'#jobs tbody tr[data-job-id="{job_id}"]')).to_have_attribute(
            "data-state", "succeeded", timeout=TIMEOUT_MS)
        screenshot(page, "console-real-service")
        assert bridge.executed == [job_id]
        assert page.js_errors == []

        # The job's audit file: downloaded through the API, intact against the stored head.
        from service.audit import verify

        deadline = time.monotonic() + WAIT_S
        result = None
        while time.monotonic() < deadline:
            job = alice.get(f"/v1/jobs/{job_id}").json()
            audit = alice.get(f"/v1/jobs/{job_id}/audit")
            if audit.status_code == 200 and job.get("audit_head"):
                path = SCREENSHOT_DIR / "console-e2e.mcap"
                SCREENSHOT_DIR.mkdir(parents=True, exist_ok=True)
                path.write_bytes(audit.content)
                result = verify(path, job["audit_head"])
                if result.exit_code == 0:
                    break
            time.sleep(0.2)
        assert result is not None and result.exit_code == 0, result and result.detail

        # The same file through the page's download button.
        with page.expect_download(timeout=TIMEOUT_MS) as download:
            page.click("#btn-audit")
        saved = tmp_path / "from-browser.mcap"
        download.value.save_as(saved)
        assert download.value.suggested_filename == f"{job_id}.mcap"
        assert verify(saved, job["audit_head"]).exit_code == 0
