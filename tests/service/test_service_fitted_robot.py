"""A built-in scenario run over HTTP with another registered robot (``"robot": NAME``) is the task the command
line runs for ``regrasp plan/survey --robot``: fitted to that robot, the same way, and recorded in the plan."""

from __future__ import annotations

import json
from typing import Iterator

import pytest
from click.testing import CliRunner
from conftest import Server, wait_state

from service.cli.main import cli
from service.settings import DEFAULT_HANDLERS
from tests.planning.robot.small_humanoid import write_small_humanoid

#: Generous for a loaded 2-core machine; the small humanoid's fitted task plans in seconds.
JOB_TIMEOUT_S = 300
SURVEY = {"until": "states", "states_per_seed": 20, "seeds_min": 1, "seeds_max": 1}


@pytest.fixture(scope="module")
def robot_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, str]]:
    folder = tmp_path_factory.mktemp("robots")
    spec_path = write_small_humanoid(folder)
    cache = tmp_path_factory.mktemp("cache")
    mp = pytest.MonkeyPatch()
    mp.setenv("REGRASP_CACHE_DIR", str(cache))  # the server and the command line below share it
    srv = Server(tmp_path_factory.mktemp("fitted"), workers=1, handlers=DEFAULT_HANDLERS, check_scenario_names="true",
                 robot_dirs=str(folder)).start()
    try:
        yield srv, str(spec_path)
    finally:
        srv.stop()
        mp.undo()


def _job(srv: Server, kind: str, request: dict) -> dict:
    with srv.client("alice") as alice:
        r = alice.post("/v1/jobs", json={"kind": kind, "request": request})
        assert r.status_code == 202, r.text
        job = wait_state(alice, r.json()["id"], {"planned", "succeeded", "failed", "canceled"}, timeout=JOB_TIMEOUT_S)
        assert job["state"] in ("planned", "succeeded"), (job["error"], srv.log_path.read_text()[-2000:])
        return job["result"]


def test_a_plan_and_a_survey_job_with_another_robot_run_the_task_fitted_as_the_command_line_fits_it(robot_server, tmp_path):
    srv, spec_path = robot_server
    plan = _job(srv, "plan", {"scenario": "upright", "robot": "small_humanoid", "hands": "right-right", "seed": 1})
    fitted = plan["scenario"]["fitted"]
    assert fitted["robot"] == "small_humanoid" and fitted["from_robot"] == "hrp5p" and fitted["scale"] < 1.0
    assert plan["status"] == "solved" and plan["robot"]["name"] == "small_humanoid", plan["failure"]
    res = CliRunner().invoke(cli, ["plan", "--scenario", "upright", "--robot", spec_path, "--hands", "right-right",
                                   "--seed", "1", "--out", str(tmp_path / "plan.json"), "--quiet"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    by_cli = json.loads((tmp_path / "plan.json").read_text())
    assert by_cli["scenario"]["fitted"] == fitted
    assert by_cli["object"] == plan["object"] and by_cli["scenario"]["tables"] == plan["scenario"]["tables"]
    survey = _job(srv, "survey", {"scenario": "upright", "robot": "small_humanoid", "seed": 1, **SURVEY})
    assert survey["robot"]["name"] == "small_humanoid"
    assert survey["object"]["mass_kg"] == plan["object"]["mass_kg"] == fitted["mass_kg"] < 8.0
    assert survey["object"]["start_pose"] == plan["object"]["start_pose"]
    # the command line's survey of the same request: the same fitted task, the same answer
    res = CliRunner().invoke(cli, ["survey", "--scenario", "upright", "--robot", spec_path, "--seed", "1", "--until",
                                   "states", "--states", "20", "--seeds-min", "1", "--seeds-max", "1", "--json"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    by_cli = json.loads(res.output)
    assert by_cli["object"] == survey["object"] and by_cli["rows"] == survey["rows"]
