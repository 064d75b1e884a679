"""The console's cancel and stop buttons, and its buttons by the token's roles, in headless Chromium (fake API).

The fake API (fake_api.py) follows the contract's roles: planner (submit, cancel
own), approver (approve, reject; not the submitter's own job), operator (dispatch,
stop), admin (everything); ``dan`` holds no role and only reads.
"""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from .ui import click_and_confirm, login, open_job, use_token

TIMEOUT_MS = 10_000
ACTIONS = ("approve", "reject", "dispatch", "stop", "cancel")
#: Execution steps long enough that a dispatched job is still dispatching when stop is clicked.
SLOW_STEP_S = 30.0
#: A stopped execution's thread ends at once (its stop event wakes it), well before a step.
EXECUTION_END_S = 2.0


def _buttons(page) -> dict[str, str]:
    """Each action button as the operator sees it: 'hidden', 'disabled' or 'enabled'."""
    return page.evaluate(
        """(actions) => Object.fromEntries(actions.map((a) => {
             const b = document.getElementById("btn-" + a);
             return [a, b.hidden || b.offsetParent === null ? "hidden" : (b.disabled ? "disabled" : "enabled")];
           }))""", list(ACTIONS))


def _expect_buttons(page, expected: dict[str, str]) -> None:
    """Wait until the buttons settle (the roles arrive with GET /v1/me), then compare all of them."""
    for action, how in expected.items():
        button = page.locator(f"#btn-{action}")
        if how == "hidden":
            expect(button).to_be_hidden(timeout=TIMEOUT_MS)
        else:
            expect(button).to_be_visible(timeout=TIMEOUT_MS)
            (expect(button).to_be_enabled if how == "enabled" else expect(button).to_be_disabled)(timeout=TIMEOUT_MS)
    assert _buttons(page) == expected


# ------------------------------------------------------------------ cancel
def test_cancel_button_cancels_a_queued_job(page, fake_server):
    url, store = fake_server
    job = store.add("plan", "alice", state="queued")
    login(page, url, "planner-token-alice")
    open_job(page, job["id"])
    expect(page.locator("#job-state")).to_have_text("queued")
    _expect_buttons(page, {"approve": "hidden", "reject": "hidden", "dispatch": "hidden", "stop": "hidden",
                           "cancel": "enabled"})
    page.click("#btn-cancel")
    expect(page.locator("#job-state")).to_have_text("canceled", timeout=TIMEOUT_MS)
    expect(page.locator(f'#jobs tbody tr[data-job-id="{job["id"]}"]')).to_have_attribute(
        "data-state", "canceled", timeout=TIMEOUT_MS)
    expect(page.locator("#btn-cancel")).to_be_hidden()
    assert store.jobs[job["id"]]["state"] == "canceled"
    assert page.js_errors == []


def test_cancel_button_cancels_a_planning_job(page, fake_server):
    url, store = fake_server
    job = store.add("plan", "alice", state="planning")
    login(page, url, "planner-token-alice")
    open_job(page, job["id"])
    page.click("#btn-cancel")
    expect(page.locator("#job-state")).to_have_text("canceled", timeout=TIMEOUT_MS)
    assert store.jobs[job["id"]]["state"] == "canceled"


# -------------------------------------------------------------------- stop
def test_stop_button_stops_a_dispatching_job(page, fake_server):
    url, store = fake_server
    store.execution_step_s = SLOW_STEP_S
    store.approve(store.plan_id)
    login(page, url, "operator-token-carol")
    open_job(page, store.plan_id)
    click_and_confirm(page, "dispatch")
    expect(page.locator("#job-state")).to_have_text("dispatching", timeout=TIMEOUT_MS)
    _expect_buttons(page, {"approve": "hidden", "reject": "hidden", "dispatch": "hidden", "stop": "enabled",
                           "cancel": "hidden"})
    page.click("#btn-stop")
    expect(page.locator("#job-state")).to_have_text("aborted", timeout=TIMEOUT_MS)
    expect(page.locator("#job-message")).to_contain_text("stopped by carol")
    expect(page.locator("#btn-stop")).to_be_hidden()
    # The execution itself ended: its thread is gone long before its next step, and it never ran.
    thread, stop = store.executions[store.plan_id]
    thread.join(EXECUTION_END_S)
    assert stop.is_set() and not thread.is_alive()
    states = [e["state"] for e in store.events if e["job_id"] == store.plan_id and e["kind"] == "state"]
    assert states[-2:] == ["dispatching", "aborted"] and "executing" not in states
    assert store.jobs[store.plan_id]["state"] == "aborted"
    assert page.js_errors == []


def test_stop_button_stops_an_executing_job(page, fake_server):
    url, store = fake_server
    store.execution_step_s = 1.0  # 8 steps: executing for 8 s unless stopped
    store.approve(store.plan_id)
    login(page, url, "operator-token-carol")
    open_job(page, store.plan_id)
    click_and_confirm(page, "dispatch")
    expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
    page.click("#btn-stop")
    expect(page.locator("#job-state")).to_have_text("aborted", timeout=TIMEOUT_MS)
    thread, _ = store.executions[store.plan_id]
    thread.join(EXECUTION_END_S)
    assert not thread.is_alive()
    job = store.jobs[store.plan_id]
    assert job["state"] == "aborted" and job["progress"] < 1.0


# ------------------------------------------------------------------- roles
H, D, E = "hidden", "disabled", "enabled"
# On alice's planned plan: (token, approve, reject, dispatch, stop, cancel, submit form shown).
PLANNED_CASES = [
    ("viewer-token-dan", H, H, H, H, D, False),          # reads only (cancel: not his job)
    ("planner-token-alice", H, H, H, H, E, True),        # submitter: may cancel, not approve
    ("approver-token-bob", E, E, H, H, D, False),        # reviews; cannot submit
    ("operator-token-carol", H, H, H, H, D, False),      # nothing to do before approval
    ("admin-token-erin", E, E, H, H, E, True),           # every role
]


@pytest.mark.parametrize("token, approve, reject, dispatch, stop, cancel, submit", PLANNED_CASES,
                         ids=[c[0] for c in PLANNED_CASES])
def test_buttons_on_a_planned_job_follow_the_token_roles(page, fake_server, token, approve, reject, dispatch, stop,
                                                         cancel, submit):
    url, store = fake_server
    login(page, url, token)
    open_job(page, store.plan_id)
    expect(page.locator("#job-state")).to_have_text("planned")
    _expect_buttons(page, {"approve": approve, "reject": reject, "dispatch": dispatch, "stop": stop,
                           "cancel": cancel})
    (expect(page.locator("#submit-box")).to_be_visible if submit else expect(page.locator("#submit-box")).to_be_hidden)()
    expect(page.locator("#btn-audit")).to_be_visible()  # any authenticated user may read the audit file
    assert page.js_errors == []


def test_a_viewer_sees_no_action_and_who_he_is(page, fake_server):
    url, store = fake_server
    store.approve(store.plan_id)
    login(page, url, "viewer-token-dan", whoami="signed in as dan (read only)")
    open_job(page, store.plan_id)
    expect(page.locator("#job-state")).to_have_text("approved")
    _expect_buttons(page, {"approve": H, "reject": H, "dispatch": H, "stop": H, "cancel": D})
    expect(page.locator("#btn-cancel")).to_have_attribute("title", "only the submitter (alice) or an admin can cancel "
                                                                   "this job")
    expect(page.locator("#submit-box")).to_be_hidden()


def test_an_operator_sees_dispatch_on_an_approved_job_but_an_approver_does_not(page, fake_server):
    url, store = fake_server
    store.approve(store.plan_id)
    login(page, url, "operator-token-carol", whoami="signed in as carol (operator)")
    open_job(page, store.plan_id)
    _expect_buttons(page, {"approve": H, "reject": H, "dispatch": E, "stop": H, "cancel": D})
    # The same page, another token: the buttons follow at once.
    use_token(page, "approver-token-bob", whoami="signed in as bob (approver)")
    _expect_buttons(page, {"approve": H, "reject": H, "dispatch": H, "stop": H, "cancel": D})


def test_two_person_rule_disables_approval_of_ones_own_plan(page, fake_server):
    url, store = fake_server
    own = store.add("plan", "frank", state="planned")
    login(page, url, "planner-approver-token-frank")
    open_job(page, own["id"])
    _expect_buttons(page, {"approve": D, "reject": D, "dispatch": H, "stop": H, "cancel": E})
    expect(page.locator("#btn-approve")).to_have_attribute("title", "two-person rule: you submitted this job; "
                                                                    "another approver must review it")
    # alice's plan is not his own: he may review it.
    open_job(page, store.plan_id)
    _expect_buttons(page, {"approve": E, "reject": E, "dispatch": H, "stop": H, "cancel": D})
    expect(page.locator("#submit-box")).to_be_visible()


def test_an_unknown_token_gets_no_action(page, fake_server):
    url, store = fake_server
    login(page, url, "not-a-token-at-all")
    expect(page.locator("#banner")).to_contain_text("401", timeout=TIMEOUT_MS)
    expect(page.locator("#submit-box")).to_be_hidden()
    assert page.evaluate("regraspConsole.state.me === undefined")  # refused: roles unknown, nothing offered


def test_stop_stays_on_screen_for_an_execution_while_another_job_is_shown(page, fake_server):
    url, store = fake_server
    store.execution_step_s = 1.0  # 8 steps: executing for 8 s unless stopped
    store.approve(store.plan_id)
    login(page, url, "operator-token-carol")
    open_job(page, store.plan_id)
    click_and_confirm(page, "dispatch")
    expect(page.locator("#job-state")).to_have_text("executing", timeout=TIMEOUT_MS)
    survey_id = next(j for j, job in store.jobs.items() if job["kind"] == "survey")
    open_job(page, survey_id)  # the operator looks at another job
    expect(page.locator("#exec-bar")).to_be_visible(timeout=TIMEOUT_MS)
    expect(page.locator("#exec-job")).to_have_text(store.plan_id[:8])
    page.click("#btn-stop")
    expect(page.locator("#exec-bar")).to_be_hidden(timeout=TIMEOUT_MS)
    assert store.jobs[store.plan_id]["state"] == "aborted"
    assert store.jobs[survey_id]["state"] == "succeeded"
    assert page.js_errors == []
