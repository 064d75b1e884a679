"""The console's fake API answers as the real API's OpenAPI document says, and a change to the API is caught.

No browser: the fake's routes are driven with an HTTP client through every action the console
takes, each exchange validated against the real document (``openapi_check``). The browser tests
run the same check on every request the page makes (``conftest.fake_server``).
"""

from __future__ import annotations

import copy
import time

import httpx
import pytest

from .conftest import serve
from .fake_api import create_app
from .openapi_check import ContractCheck

H = {name: {"Authorization": f"Bearer {token}"} for name, token in
     (("alice", "planner-token-alice"), ("bob", "approver-token-bob"), ("carol", "operator-token-carol"))}


def _drive(url: str, store) -> None:
    """Every route the console calls, as the console calls it."""
    with httpx.Client(base_url=url, timeout=10) as c:
        assert c.get("/healthz").status_code == 200
        assert c.get("/v1/me", headers=H["bob"]).json()["roles"] == ["approver"]
        assert c.get("/v1/jobs").status_code == 401
        jobs = c.get("/v1/jobs", headers=H["alice"]).json()["jobs"]
        assert len(jobs) == 2
        c.get("/v1/catalogue", headers=H["alice"]).raise_for_status()
        plan_id = store.plan_id
        c.get(f"/v1/jobs/{plan_id}", headers=H["alice"]).raise_for_status()
        c.get(f"/v1/jobs/{plan_id}/risk", headers=H["alice"]).raise_for_status()
        assert c.post(f"/v1/jobs/{plan_id}/approve", headers=H["alice"], json={}).status_code == 403
        sha = c.get(f"/v1/jobs/{plan_id}", headers=H["bob"]).json()["plan_sha256"]
        assert c.post(f"/v1/jobs/{plan_id}/approve", headers=H["bob"], json={"plan_sha256": sha}).status_code == 200
        r = c.post(f"/v1/jobs/{plan_id}/dispatch", headers=H["carol"])
        assert r.is_success and r.json()["result"] is None
        assert c.post(f"/v1/jobs/{plan_id}/stop", headers=H["carol"], json={"reason": "test"}).is_success
        other = store.add("plan", "alice", state="planned")
        r = c.post(f"/v1/jobs/{other['id']}/reject", headers=H["bob"], json={"reason": "too close to the table"})
        assert r.status_code == 200 and r.json()["state"] == "rejected"
        queued = c.post("/v1/jobs", headers=H["alice"], json={"kind": "plan", "request": {"scenario": "upright"}})
        assert queued.is_success
        assert c.post(f"/v1/jobs/{queued.json()['id']}/cancel", headers=H["alice"],
                      json={"reason": "test"}).is_success
        time.sleep(0.05)


def test_the_fake_answers_as_the_real_openapi_document_says(real_openapi_doc) -> None:
    check = ContractCheck(real_openapi_doc)
    app = create_app(check)
    with serve(app) as url:
        _drive(url, app.state.store)
    assert check.violations == []


@pytest.mark.parametrize("change", ["job gains a required field", "reject route removed", "approve body renamed",
                                    "dispatch answers 200"])
def test_a_change_to_the_api_fails_the_check(real_openapi_doc, change: str) -> None:
    doc = copy.deepcopy(real_openapi_doc)
    if change == "job gains a required field":
        doc["components"]["schemas"]["Job"]["properties"]["site"] = {"type": "string"}
        doc["components"]["schemas"]["Job"]["required"].append("site")
    elif change == "reject route removed":
        del doc["paths"]["/v1/jobs/{job_id}/reject"]
    elif change == "approve body renamed":
        body = doc["paths"]["/v1/jobs/{job_id}/approve"]["post"]["requestBody"]["content"]["application/json"]
        body["schema"] = {"type": "object", "properties": {"sha": {"type": "string"}}, "additionalProperties": False}
    else:
        responses = doc["paths"]["/v1/jobs/{job_id}/dispatch"]["post"]["responses"]
        responses["200"] = responses.pop("202")
    check = ContractCheck(doc)
    app = create_app(check)
    with serve(app) as url:
        _drive(url, app.state.store)
    assert check.violations, f"the check missed: {change}"
