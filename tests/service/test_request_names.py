"""The worker never loads a file a request names, and its errors quote neither files nor class names.

These run the worker's own entry points (planner.jobs.entry through service.jobs.worker_process) in
this process, on requests that reach the worker without the API's checks (an older API
replica, a row written by hand): the worker checks every name again itself.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
from conftest import inline_scenario

from planner.jobs.request_names import (
    RequestNameError,
    check_request,
    looks_like_path,
    resolve_request,
)
from service.jobs.worker_process import INTERNAL_ERROR_MESSAGE, JobHandlers, failure_of

SECRET = "db-password-hunter2-and-a-full-admin-token"


class Ctx:
    def progress(self, fraction: float, message: str) -> None:
        pass

    def cancelled(self) -> bool:
        return False


@pytest.fixture
def secret_files(tmp_path: Path) -> dict[str, Path]:
    """Files a hostile request points at: a stance-shaped YAML, a token file, a mesh, a robot spec."""
    files = {
        "stance": tmp_path / "stance.yaml",
        "tokens": tmp_path / "tokens.json",
        "mesh": tmp_path / "secret.obj",
        "robot": tmp_path / "robot.yaml",
    }
    files["stance"].write_text(f"name: {SECRET}\nfeet: [{{frame: {SECRET}, pose: [0, 0, 0, 0, 0, 0, 1]}}]\n")
    files["tokens"].write_text('{"%s": {"user": "root", "roles": ["admin"]}}' % SECRET)
    files["mesh"].write_text(f"# {SECRET}\nv 0 0 0\n")
    files["robot"].write_text(f"name: {SECRET}\n")
    return files


def _requests(files: dict[str, Path]) -> list[dict[str, Any]]:
    relative = os.path.relpath(files["tokens"])
    return [
        {"scenario": "upright", "stance": str(files["stance"])},
        {"scenario": "upright", "stance": str(files["tokens"])},
        {"scenario": "upright", "stance": relative},
        {"scenario": str(files["stance"])},
        {"scenario": relative},
        {"scenario": "upright", "robot": str(files["robot"])[:-5]},
        {"scenario": inline_scenario(stance=str(files["stance"]))},
        {"scenario": inline_scenario(robot="../" * 12 + str(files["robot"])[1:-5])},
        {"scenario": inline_scenario(object={"shape": "mesh", "mesh": {"path": str(files["mesh"])}, "mass_kg": 2.0})},
    ]


def test_the_worker_refuses_every_file_a_request_names_without_quoting_it(secret_files: dict[str, Path]) -> None:
    jobs = JobHandlers({"plan": "planner.jobs.entry:run_plan", "survey": "planner.jobs.entry:run_survey"}, robot=None)
    for request in _requests(secret_files):
        for kind in ("plan", "survey"):
            tag, error = jobs.run(kind, request, Ctx())
            assert tag == "error" and error["code"] == "INVALID_REQUEST", (request, error)
            assert SECRET not in error["message"], (request, error)
            assert "never a file" in error["message"] or "registered mesh" in error["message"], error
            assert "Error" not in error["message"], error  # no class name


def test_a_named_scenario_is_the_builtin_even_with_a_file_of_that_name_in_the_cwd(tmp_path: Path,
                                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    Path("upright").write_text(SECRET)
    Path("upright.yaml").write_text(SECRET)
    resolved = resolve_request({"scenario": "upright", "robot": "jvrc1", "seed": 3})
    assert resolved["scenario"]["name"] == "upright" and resolved["scenario"]["robot"] == "jvrc1"
    assert "robot" not in resolved and resolved["seed"] == 3
    mesh = resolved["scenario"]["object"]["mesh"]
    assert Path(mesh["path"]).is_file() and Path(mesh["path"]).parent.name == "scenario_data"


def test_a_registered_mesh_by_name_is_loaded_from_the_planner_data() -> None:
    from planner.scene.scenarios import load_scenario

    doc = inline_scenario(object={"shape": "mesh", "mesh": {"name": "carrier_px"}, "mass_kg": 2.0})
    resolved = resolve_request({"scenario": doc})
    scenario = load_scenario(resolved["scenario"])
    assert Path(scenario.object.mesh.path).name == "carrier_px.obj"
    with pytest.raises(RequestNameError, match="valid meshes: carrier_nx, carrier_px"):
        check_request({"scenario": inline_scenario(object={"shape": "mesh", "mesh": {"name": "teapot"}, "mass_kg": 2.0})})


@pytest.mark.parametrize("value", ["a/b", "/etc/passwd", "..", "x..y", ".hidden", "tokens.json", "x.yaml", "a\\b",
                                   "", "a b", "x" * 200])
def test_what_reads_as_a_path(value: str) -> None:
    assert looks_like_path(value)


@pytest.mark.parametrize("value", ["upright", "one-legged", "drill-handover", "busy-1.5", "carrier_px", "hrp5p"])
def test_what_reads_as_a_name(value: str) -> None:
    assert not looks_like_path(value)


def test_an_unexpected_failure_keeps_its_class_and_text_out_of_the_job_error() -> None:
    class SecretLeak(RuntimeError):
        pass

    error = failure_of(SecretLeak(f"while reading {SECRET}"))
    assert error == {"code": "ERROR", "message": INTERNAL_ERROR_MESSAGE}
    from pydantic import BaseModel, ValidationError

    class Box(BaseModel):
        size: list[float]

    with pytest.raises(ValidationError) as info:
        Box.model_validate({"size": "x"})
    error = failure_of(info.value)
    assert error["code"] == "INVALID_REQUEST" and "size" in error["message"] and "Box" not in error["message"]
