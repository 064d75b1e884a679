"""Browser-test fixtures: a real uvicorn server on 127.0.0.1 and Debian's headless Chromium.

Playwright drives the system browser through ``executable_path``; browser
downloads (``playwright install``) do not work here and are never attempted.
The tests skip, saying why, when the browser or Playwright is missing.
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import pytest

CHROMIUM = os.environ.get("REGRASP_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
]
SERVER_START_TIMEOUT_S = 20.0
SCREENSHOT_DIR = Path(os.environ.get("REGRASP_SCREENSHOT_DIR", "/tmp/regrasp-console-screenshots"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def serve(app) -> Iterator[str]:
    """Run ``app`` under a real uvicorn server on loopback; yields its base URL."""
    import uvicorn

    port = _free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on",
                                           timeout_graceful_shutdown=1))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + SERVER_START_TIMEOUT_S
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("the test server did not start")
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10)


@pytest.fixture(scope="session")
def browser():
    if not Path(CHROMIUM).is_file() and shutil.which("chromium") is None:
        pytest.skip(f"no Chromium at {CHROMIUM}: install Debian's package (apt-get install -y chromium) "
                    "to run the console's browser tests")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("Playwright for Python is not installed (pip install playwright; no browser download needed)")
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture()
def page(browser):
    context = browser.new_context(viewport={"width": 1400, "height": 1000})
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda exc: errors.append(str(exc)))
    pg.js_errors = errors  # type: ignore[attr-defined]
    try:
        yield pg
    finally:
        context.close()


@pytest.fixture(scope="session")
def real_openapi_doc() -> dict:
    """The real service's OpenAPI document, which the fake is held to."""
    from .openapi_check import real_openapi

    return real_openapi()


@pytest.fixture()
def fake_server(real_openapi_doc) -> Iterator[tuple[str, object]]:
    """The fake API; every exchange with it is checked against the real OpenAPI document, and the test
    fails if one does not match (the fake must not drift from the API it stands for)."""
    from .fake_api import create_app
    from .openapi_check import ContractCheck

    check = ContractCheck(real_openapi_doc)
    app = create_app(check)
    with serve(app) as url:
        yield url, app.state.store
    assert not check.violations, "the fake API drifted from the real one:\n" + "\n".join(check.violations[:20])


def screenshot(page, name: str) -> Path:
    SCREENSHOT_DIR.mkdir(parents=True, exist_ok=True)
    path = SCREENSHOT_DIR / f"{name}.png"
    page.screenshot(path=str(path), full_page=True)
    return path
