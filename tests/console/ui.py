"""Steps the console's browser tests share: sign in with a token, switch tokens, open a job."""

from __future__ import annotations

from playwright.sync_api import expect

#: Default wait for the console to reflect a change, ms.
TIMEOUT_MS = 10_000


def use_token(page, token: str, whoami: str | None = None, timeout_ms: int = TIMEOUT_MS) -> None:
    """Save a token in the open console; with ``whoami``, wait until the header names its holder."""
    page.fill("#token", token)
    page.click("#token-save")
    if whoami is not None:
        expect(page.locator("#whoami")).to_have_text(whoami, timeout=timeout_ms)


def login(page, url: str, token: str, whoami: str | None = None, timeout_ms: int = TIMEOUT_MS) -> None:
    """Open the console and sign in."""
    page.goto(url + "/")
    use_token(page, token, whoami, timeout_ms)


def open_job(page, job_id: str, timeout_ms: int = TIMEOUT_MS) -> None:
    """Click the job's row and wait until its details are shown."""
    page.click(f'#jobs tbody tr[data-job-id="{job_id}"]', timeout=timeout_ms)
    expect(page.locator("#job-id")).to_have_text(job_id, timeout=timeout_ms)


def confirm(page, action: str, plan_sha256: str | None = None, timeout_ms: int = TIMEOUT_MS) -> None:
    """Answer the console's confirmation of ``action`` (approve, dispatch) with Confirm.

    With ``plan_sha256``, first check that the dialog shows that plan's hash prefix."""
    dialog = page.locator("#confirm")
    expect(dialog).to_be_visible(timeout=timeout_ms)
    expect(dialog).to_have_attribute("data-action", action)
    if plan_sha256 is not None:
        expect(page.locator("#confirm-hash")).to_have_text(plan_sha256[:12])
    page.click("#confirm-ok")
    expect(dialog).to_be_hidden(timeout=timeout_ms)


def click_and_confirm(page, action: str, plan_sha256: str | None = None, timeout_ms: int = TIMEOUT_MS) -> None:
    """Click an action's button and confirm it."""
    page.click(f"#btn-{action}", timeout=timeout_ms)
    confirm(page, action, plan_sha256, timeout_ms)
