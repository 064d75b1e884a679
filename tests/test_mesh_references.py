"""Object meshes by registered name or by a path relative to the scenario file (docs/contract.md section 2).

`regrasp scenario show NAME` prints a scenario that works saved anywhere, and neither a scenario
dump nor a plan file holds the absolute path of one checkout.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from planner.scene.meshes import MESH_DIR, mesh_file, portable_dump, registered_meshes
from planner.scene.scenarios import (
    ScenarioError,
    builtin_names,
    load_builtin,
    load_scenario_file,
    with_overrides,
)
from service.cli.main import cli

ROOT = Path(__file__).resolve().parent.parent


def _paths(doc) -> list[str]:
    """Every string in a document that looks like an absolute file path."""
    out = []
    if isinstance(doc, dict):
        for v in doc.values():
            out += _paths(v)
    elif isinstance(doc, list):
        for v in doc:
            out += _paths(v)
    elif isinstance(doc, str) and doc.startswith("/"):
        out.append(doc)
    return out


def test_the_builtin_meshes_are_registered_by_name():
    assert {"carrier_nx", "carrier_px"} <= set(registered_meshes())
    assert mesh_file("carrier_px") == MESH_DIR / "carrier_px.obj"
    with pytest.raises(ValueError, match="unknown mesh 'nope'; registered meshes: carrier_nx, carrier_px"):
        mesh_file("nope")


@pytest.mark.parametrize("name", builtin_names())
def test_scenario_show_prints_a_scenario_that_works_saved_anywhere(tmp_path, name):
    out = CliRunner().invoke(cli, ["scenario", "show", name])
    assert out.exit_code == 0, out.output
    doc = yaml.safe_load(out.output)
    assert _paths(doc) == []
    saved = tmp_path / "elsewhere" / f"{name}.yaml"
    saved.parent.mkdir()
    saved.write_text(out.output)
    again = load_scenario_file(saved)
    original = load_builtin(name)
    assert again.object == original.object  # the same mesh file, found by its name
    if original.robot == "talos":
        pytest.importorskip("cmeel", reason="TALOS needs the example-robot-data package (the `talos` extra)")
    check = CliRunner().invoke(cli, ["scenario", "check", str(saved)])
    assert check.exit_code == 0, check.output


def test_a_relative_mesh_path_resolves_against_the_scenario_file_and_dumps_as_written(tmp_path, monkeypatch):
    folder = tmp_path / "task"
    folder.mkdir()
    shutil.copy(MESH_DIR / "carrier_px.obj", folder / "part.obj")
    doc = yaml.safe_load(CliRunner().invoke(cli, ["scenario", "show", "upright"]).output)
    doc["object"]["mesh"] = {"path": "part.obj", "scale": 1.0}
    (folder / "task.yaml").write_text(yaml.safe_dump(doc))
    monkeypatch.chdir(tmp_path)  # not the scenario's folder
    sc = load_scenario_file(folder / "task.yaml")
    assert Path(sc.object.mesh.path) == (folder / "part.obj").resolve()  # found beside the scenario file
    assert portable_dump(sc)["object"]["mesh"] == {"path": "part.obj", "scale": 1.0}
    overridden = with_overrides(sc, threshold_m=0.05)
    assert portable_dump(overridden)["object"]["mesh"] == {"path": "part.obj", "scale": 1.0}


def test_an_unknown_mesh_name_is_refused_with_the_registered_ones(tmp_path):
    doc = yaml.safe_load(CliRunner().invoke(cli, ["scenario", "show", "upright"]).output)
    doc["object"]["mesh"] = {"name": "teapot"}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ScenarioError, match="unknown mesh 'teapot'; registered meshes: carrier_nx, carrier_px"):
        load_scenario_file(tmp_path / "t.yaml")


def test_a_mesh_needs_a_name_or_a_path(tmp_path):
    doc = yaml.safe_load(CliRunner().invoke(cli, ["scenario", "show", "upright"]).output)
    doc["object"]["mesh"] = {"scale": 1.0}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ScenarioError, match="a mesh needs name: REGISTERED or path: FILE"):
        load_scenario_file(tmp_path / "t.yaml")


def test_a_plan_file_stores_the_mesh_by_name(tmp_path):
    """A plan of a mesh scenario (the 0 mm planner, the quickest) names its mesh, not a checkout's path."""
    out = CliRunner().invoke(cli, ["plan", "--scenario", "upright", "--hands", "left-left", "--threshold-mm", "0",
                                   "--out", str(tmp_path / "plan.json"), "--quiet"])
    assert out.exit_code in (0, 1), out.output
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["scenario"]["object"]["mesh"] == {"name": "carrier_px", "scale": 1.0}
    assert _paths(plan["scenario"]) == []


def test_an_object_built_from_a_mesh_name_alone_finds_the_registered_file():
    from planner.scene.objects import build_object
    from schemas.scenario import ObjectDef

    by_name = build_object(ObjectDef(shape="mesh", mesh={"name": "carrier_px"}, mass_kg=8.0))
    by_path = build_object(ObjectDef(shape="mesh", mesh={"path": str(MESH_DIR / "carrier_px.obj")}, mass_kg=8.0))
    assert by_name.content_hash == by_path.content_hash
    with pytest.raises(ValueError, match="unknown mesh 'teapot'"):
        build_object(ObjectDef(shape="mesh", mesh={"name": "teapot"}, mass_kg=8.0))
