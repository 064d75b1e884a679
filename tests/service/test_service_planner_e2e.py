"""The real planner behind the service: a plan job and a survey job end to end.

These run once the planner's job functions exist (planner.jobs, planner.survey).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import httpx
import pytest
from conftest import Server, wait_state

pytest.importorskip("planner.jobs", reason="the planner's job functions (planner.jobs) are not installed yet")

from schemas.plan import Plan, plan_sha256  # noqa: E402
from service.settings import DEFAULT_HANDLERS  # noqa: E402

#: Generous: the first plan on a busy 2-core machine includes the object and grasp set-up.
PLAN_TIMEOUT_S = 240


@pytest.fixture(scope="module")
def real_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    srv = Server(tmp_path_factory.mktemp("real"), workers=2, handlers=DEFAULT_HANDLERS, check_scenario_names="true",
                 preload_robot="true").start()
    try:
        yield srv
    finally:
        srv.stop()


def test_unknown_scenario_is_refused_at_submit(real_server: Server) -> None:
    with real_server.client("alice") as c:
        r = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "no-such-scenario"}})
        assert r.status_code == 422 and "upright" in r.json()["detail"]


def test_plan_job_end_to_end(real_server: Server) -> None:
    with real_server.client("alice") as alice, real_server.client("bob") as bob:
        r = alice.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "upright", "seed": 1}})
        assert r.status_code == 202
        job = wait_state(alice, r.json()["id"], {"planned", "failed", "canceled"}, timeout=PLAN_TIMEOUT_S)
        if job["state"] == "failed":
            assert job["error"]["code"], job  # an infeasible plan carries the planner's failure code
            pytest.skip(f"the planner found no plan for 'upright' yet: {job['error']}")
        plan = job["result"]
        Plan.model_validate(plan)
        assert plan["status"] == "solved" and job["plan_sha256"] == plan_sha256(plan)
        assert job["provenance"]["robot_sha256"] == plan["robot"]["urdf_sha256"]
        approved = bob.post(f"/v1/jobs/{job['id']}/approve", json={"plan_sha256": job["plan_sha256"]})
        assert approved.status_code == 200 and approved.json()["state"] == "approved"


def test_survey_job_end_to_end(real_server: Server) -> None:
    pytest.importorskip("planner.survey", reason="the survey (planner.survey) is not installed yet")
    with real_server.client("alice") as alice:
        r = alice.post("/v1/jobs", json={"kind": "survey", "request": {"scenario": "upright", "seed": 1,
                                                                      "states_per_configuration": 30}})
        job = wait_state(alice, r.json()["id"], {"succeeded", "failed"}, timeout=PLAN_TIMEOUT_S)
        assert job["state"] == "succeeded", job["error"]
        survey = job["result"]
        assert survey["schema"] == "regrasp.survey/1" and len(survey["rows"]) >= 1
