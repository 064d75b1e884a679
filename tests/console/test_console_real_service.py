"""End to end: the console on the real service (FastAPI app, SQLite job store, worker
processes, audit pump, real uvicorn) in headless Chromium. Approve, then dispatch, and the
state changes on screen; the job's audit file then verifies against its stored head. Cancel
a planning job and stop an executing one from the page; the buttons follow the token's roles
(GET /v1/me).

The robot side is a scripted bridge (the service's ``Bridge`` interface) that plays a
short execution; the zenoh bridge and the simulated controller have their own tests.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

import httpx
import pytest
from playwright.sync_api import expect

from tests.service.conftest import wait_state

from .conftest import SCREENSHOT_DIR, screenshot, serve
from .ui import click_and_confirm, login, use_token

TOKENS = {
    "e2e-token-alice-planner": {"user": "alice", "roles": ["planner"]},
    "e2e-token-bob-approver": {"user": "bob", "roles": ["approver"]},
    "e2e-token-carol-operator": {"user": "carol", "roles": ["operator"]},
    "e2e-token-dan-viewer": {"user": "dan", "roles": []},
}
ALICE, BOB, CAROL, DAN = list(TOKENS)
TIMEOUT_MS = 20_000
WAIT_S = 60.0
EXEC_STEPS = 6
EXEC_STEP_S = 0.25
#: Steps of an execution that a test stops: far longer than the test.
LONG_EXEC_STEPS = 400


class ScriptedBridge:
    """A controller that is alive, passes the gate and plays a few segments."""

    def __init__(self) -> None:
        self.executed: list[str] = []
        self.steps = EXEC_STEPS
        #: job id -> how its execute() call ended; jobs the service asked to stop.
        self.outcomes: dict[str, str] = {}
        self.stop_requests: list[str] = []

    def controller_alive(self) -> bool:
        return True

    def execute(self, plan: dict[str, Any], *, job_id: str, approved_sha256: str, approval_expires_at: Any,
                threshold_m: float, on_event: Callable[[str, dict[str, Any]], None],
                stop_event: threading.Event):
        from service.execution.bridge import Outcome

        on_event("gate_verdict", {"passed": True, "threshold_m": threshold_m})
        steps = self.steps
        for seq in range(steps):
            if stop_event.wait(EXEC_STEP_S):
                self.outcomes[job_id] = "aborted"
                return Outcome("aborted", "stopped by an operator")
            on_event("segment", {"seq": seq, "segment_index": seq, "segment_count": steps})
        self.executed.append(job_id)
        self.outcomes[job_id] = "succeeded"
        return Outcome("succeeded", None, {"passed": True})

    def stop(self, job_id: str) -> None:
        self.stop_requests.append(job_id)

    def close(self) -> None:
        return None


@pytest.fixture(scope="module")
def real_service(tmp_path_factory: pytest.TempPathFactory):
    from service.app import create_app
    from service.settings import ServiceSettings

    settings = ServiceSettings(
        data_dir=tmp_path_factory.mktemp("console-e2e"), workers=1, tokens=TOKENS, check_scenario_names=False, preload_robot=False,
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
        wait_state(alice, job_id, {"planned"}, WAIT_S)

        login(page, url, BOB)
        page.click(f'#jobs tbody tr[data-job-id="{job_id}"]', timeout=TIMEOUT_MS)
        expect(page.locator("#job-state")).to_have_text("planned", timeout=TIMEOUT_MS)
        expect(page.locator('#com-chart polyline[data-role="com-trace"]')).to_have_count(1)
        click_and_confirm(page, "approve")
        expect(page.locator("#job-state")).to_have_text("approved", timeout=TIMEOUT_MS)
        expect(page.locator("#job-approval")).to_contain_text("bob")

        use_token(page, CAROL)
        expect(page.locator("#btn-dispatch")).to_be_visible(timeout=TIMEOUT_MS)
        click_and_confirm(page, "dispatch")
        expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
        expect(page.locator("#live-mode")).to_have_text("SSE")
        expect(page.locator("#job-state")).to_have_text("succeeded", timeout=TIMEOUT_MS)
        expect(page.locator(f'#jobs tbody tr[data-job-id="{job_id}"]')).to_have_attribute(
            "data-state", "succeeded", timeout=TIMEOUT_MS)
        screenshot(page, "console-real-service")
        assert bridge.executed.count(job_id) == 1 and bridge.outcomes[job_id] == "succeeded"
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


def _client(url: str, token: str | None) -> httpx.Client:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    return httpx.Client(base_url=url, headers=headers, timeout=10)


def test_v1_me_tells_the_token_user_and_roles(real_service):
    url, _ = real_service
    with _client(url, BOB) as bob, _client(url, DAN) as dan, _client(url, None) as nobody, \
            _client(url, "e2e-token-unknown") as stranger:
        assert bob.get("/v1/me").json() == {"user": "bob", "roles": ["approver"]}
        assert dan.get("/v1/me").json() == {"user": "dan", "roles": []}
        for refused in (nobody.get("/v1/me"), stranger.get("/v1/me")):
            assert refused.status_code == 401
            assert refused.headers["content-type"].startswith("application/problem+json")
            assert refused.headers["www-authenticate"].startswith("Bearer")


def test_buttons_follow_the_token_roles_on_the_real_service(page, real_service):
    url, _ = real_service
    with _client(url, ALICE) as alice:
        job_id = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "console-e2e"}}).json()["id"]
        wait_state(alice, job_id, {"planned"}, WAIT_S)
    # A viewer reads the plan but is offered no action and no submission.
    login(page, url, DAN, whoami="signed in as dan (read only)", timeout_ms=TIMEOUT_MS)
    page.click(f'#jobs tbody tr[data-job-id="{job_id}"]', timeout=TIMEOUT_MS)
    expect(page.locator("#job-state")).to_have_text("planned", timeout=TIMEOUT_MS)
    expect(page.locator('#com-chart polyline[data-role="com-trace"]')).to_have_count(1)
    for action in ("approve", "reject", "dispatch", "stop"):
        expect(page.locator(f"#btn-{action}")).to_be_hidden()
    expect(page.locator("#btn-cancel")).to_be_disabled()  # not his job
    expect(page.locator("#submit-box")).to_be_hidden()
    # The approver is offered approve, not dispatch nor submission.
    use_token(page, BOB, whoami="signed in as bob (approver)", timeout_ms=TIMEOUT_MS)
    expect(page.locator("#btn-approve")).to_be_enabled(timeout=TIMEOUT_MS)
    expect(page.locator("#btn-dispatch")).to_be_hidden()
    expect(page.locator("#submit-box")).to_be_hidden()
    # The submitter may cancel her plan and submit, not approve it.
    use_token(page, ALICE, whoami="signed in as alice (planner)", timeout_ms=TIMEOUT_MS)
    expect(page.locator("#btn-cancel")).to_be_enabled(timeout=TIMEOUT_MS)
    expect(page.locator("#btn-approve")).to_be_hidden()
    expect(page.locator("#submit-box")).to_be_visible()
    assert page.js_errors == []


def test_cancel_a_planning_job_from_the_console(page, real_service):
    from tests.console.console_handlers import SLOW_SCENARIO

    url, _ = real_service
    with _client(url, ALICE) as alice:
        job_id = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": SLOW_SCENARIO}}).json()["id"]
        login(page, url, ALICE)
        page.click(f'#jobs tbody tr[data-job-id="{job_id}"]', timeout=TIMEOUT_MS)
        expect(page.locator("#job-state")).to_have_text("planning", timeout=TIMEOUT_MS)
        page.click("#btn-cancel")
        expect(page.locator("#job-state")).to_have_text("canceled", timeout=TIMEOUT_MS)
        expect(page.locator("#btn-cancel")).to_be_hidden()
        job = alice.get(f"/v1/jobs/{job_id}").json()
        assert job["state"] == "canceled" and job["result"] is None
        history = alice.get(f"/v1/jobs/{job_id}/events", params={"follow": "false"}).text
        assert '"state":"planning"' in history and '"state":"canceled"' in history and '"state":"planned"' not in history
    assert page.js_errors == []


def test_stop_an_executing_job_from_the_console(page, real_service):
    url, bridge = real_service
    with _client(url, ALICE) as alice, _client(url, BOB) as bob:
        job_id = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "console-e2e"}}).json()["id"]
        planned = wait_state(alice, job_id, {"planned"}, WAIT_S)
        assert bob.post(f"/v1/jobs/{job_id}/approve", json={"plan_sha256": planned["plan_sha256"]}).status_code == 200
        bridge.steps = LONG_EXEC_STEPS
        try:
            login(page, url, CAROL)
            page.click(f'#jobs tbody tr[data-job-id="{job_id}"]', timeout=TIMEOUT_MS)
            click_and_confirm(page, "dispatch", timeout_ms=TIMEOUT_MS)
            expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
            page.click("#btn-stop")
            expect(page.locator("#job-state")).to_have_text("aborted", timeout=TIMEOUT_MS)
        finally:
            bridge.steps = EXEC_STEPS
        expect(page.locator("#job-error")).to_contain_text("ABORTED")
        expect(page.locator("#btn-stop")).to_be_hidden()
        job = alice.get(f"/v1/jobs/{job_id}").json()
        assert job["state"] == "aborted" and job["error"]["code"] == "ABORTED"
        # The robot side was told to stop and its execution ended early, not by running out.
        assert bridge.stop_requests.count(job_id) >= 1
        assert bridge.outcomes[job_id] == "aborted" and job_id not in bridge.executed
    assert page.js_errors == []
