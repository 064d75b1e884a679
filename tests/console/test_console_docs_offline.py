"""The API docs render with no internet: /docs (Swagger UI) and /redoc load only the package's files.

Every request the browser makes to a host other than the test server is aborted and recorded;
the pages must render their operations anyway and must not have tried to reach anything else.
The OpenAPI document gives every request body an example and verb operationIds.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from urllib.parse import urlparse

import httpx
import pytest
from playwright.sync_api import expect

from .conftest import screenshot, serve

ROOT = Path(__file__).resolve().parents[2]
TOKENS = {"docs-token-viewer": {"user": "vera", "roles": []}}


@pytest.fixture(scope="module")
def docs_server(tmp_path_factory: pytest.TempPathFactory):
    from service.app import create_app
    from service.execution.bridge import NoBridge
    from service.settings import ServiceSettings

    settings = ServiceSettings(data_dir=tmp_path_factory.mktemp("docs"), workers=1, tokens=TOKENS, preload_robot=False)
    with serve(create_app(settings, run_workers=False, bridge=NoBridge())) as url:
        yield url


def _offline(page, url: str) -> list[str]:
    """Abort every request to another host; returns the list of those attempted."""
    host = urlparse(url).netloc
    outside: list[str] = []

    def route(r):
        if urlparse(r.request.url).netloc == host:
            r.continue_()
        else:
            outside.append(r.request.url)
            r.abort()

    page.route("**/*", route)
    return outside


def test_swagger_ui_renders_offline(page, docs_server):
    outside = _offline(page, docs_server)
    page.goto(docs_server + "/docs")
    # Swagger UI names each operation's block by tag and operationId.
    expect(page.locator("#operations-jobs-submitJob")).to_be_visible(timeout=20_000)
    expect(page.locator("#operations-jobs-streamJobEvents")).to_be_visible()
    page.click("#operations-jobs-submitJob .opblock-summary")
    expect(page.locator("#operations-jobs-submitJob")).to_contain_text('"scenario": "upright"', timeout=10_000)
    screenshot(page, "docs-swagger-offline")
    assert outside == [] and page.js_errors == []


def test_redoc_renders_offline(page, docs_server):
    outside = _offline(page, docs_server)
    page.goto(docs_server + "/redoc")
    # Redoc lists every operation by its operationId, from the local openapi.json.
    expect(page.locator('a[href$="/jobs/submitjob"]').first).to_be_attached(timeout=30_000)
    expect(page.locator('a[href$="/jobs/streamjobevents"]').first).to_be_attached()
    screenshot(page, "docs-redoc-offline")
    assert outside == []


def test_every_request_body_has_an_example_and_every_operation_a_verb_id(docs_server):
    doc = httpx.get(docs_server + "/openapi.json", timeout=10).json()
    ops = [(path, method, op) for path, item in doc["paths"].items() for method, op in item.items()]
    ids = {op["operationId"] for _, _, op in ops}
    assert {"submitJob", "listJobs", "getJob", "streamJobEvents", "approveJob", "dispatchJob", "stopJob",
            "getJobRisk", "getCatalogue", "getRobotUrdf"} <= ids
    assert all("_" not in i and i[0].islower() for i in ids), sorted(ids)
    for path, method, op in ops:
        body = op.get("requestBody")
        if body is None:
            continue
        examples = body["content"]["application/json"].get("examples")
        assert examples, f"{method.upper()} {path} has no request example"
        for ex in examples.values():  # each example is a body the schema accepts (checked by the service below)
            assert isinstance(ex["value"], dict)


def test_the_submit_examples_are_requests_the_service_accepts(docs_server):
    """Each example of submitJob validates against the request model (the examples cannot drift from it)."""
    from schemas.jobs import JobSubmit
    from service.api.docs import BODY_EXAMPLES

    for name, ex in BODY_EXAMPLES["submitJob"].items():
        JobSubmit.model_validate(ex["value"])


def test_the_vendored_files_match_their_pinned_hashes():
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "fetch_console_vendor.py"), "--check"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    for name in ("three", "urdf-loader", "swagger-ui-dist", "redoc"):
        assert (ROOT / "service" / "console" / "vendor" / name / "LICENSE").is_file(), name


def test_the_vendor_check_catches_a_changed_or_missing_file(tmp_path, monkeypatch, capsys):
    import importlib.util
    import shutil

    spec = importlib.util.spec_from_file_location("fetch_console_vendor", ROOT / "scripts" / "fetch_console_vendor.py")
    script = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "fetch_console_vendor", script)  # dataclasses look their module up
    spec.loader.exec_module(script)  # type: ignore[union-attr]
    copy = tmp_path / "vendor"
    shutil.copytree(ROOT / "service" / "console" / "vendor", copy)
    monkeypatch.setattr(script, "VENDOR", copy)
    assert script.check() == 0
    target = copy / "three" / "build" / "three.module.js"
    target.write_bytes(target.read_bytes() + b"\n// changed")
    (copy / "redoc" / "bundles" / "redoc.standalone.js").unlink()
    assert script.check() == 1
    out = capsys.readouterr().out
    assert "MISMATCH three@0.187.0 build/three.module.js" in out and "MISSING  redoc@3.0.1 bundles/redoc.standalone.js" in out
