"""`regrasp robot info` of the built-in robots (now regrasp.robot/1 spec files) keeps the contract's fields and the
values they had in the former built-in format (tests/data/robot_info)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from service.cli.main import cli

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "robot_info"
CONTRACT_FIELDS = ("name", "urdf", "urdf_sha256", "total_mass_kg", "height_m", "joint_names", "acceleration_limits",
                   "stances", "effort_limits")


@pytest.mark.parametrize("name", ["hrp5p", "jvrc1"])
def test_robot_info_json_has_the_contract_fields_with_the_former_values(name, tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "cache"))
    res = CliRunner().invoke(cli, ["robot", "info", name, "--json"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    want = json.loads((GOLDEN / f"{name}.json").read_text())
    for key in CONTRACT_FIELDS:
        assert key in doc, key
    assert Path(doc["urdf"]).name == want["urdf"]
    for key in ("name", "description", "urdf_sha256", "dof", "joint_names", "grip", "frames", "limit_sources"):
        assert doc[key] == want[key], key
    # one acceleration and effort limit per joint (effort: every joint but the jaws), as before
    assert doc["acceleration_limits"] == want["acceleration_limits"]
    assert set(doc["acceleration_limits"]) == set(doc["joint_names"])
    assert doc["effort_limits"] == want["effort_limits"]
    assert doc["total_mass_kg"] == pytest.approx(want["total_mass_kg"], rel=0, abs=1e-12)
    assert doc["height_m"] == pytest.approx(want["height_m"], rel=0, abs=1e-12)
    assert [s["name"] for s in doc["stances"]] == [s["name"] for s in want["stances"]]
    for got, exp in zip(doc["stances"], want["stances"]):
        for key in ("base_pose", "q", "com"):
            assert got[key] == pytest.approx(exp[key], rel=0, abs=1e-9), (got["name"], key)
        assert got["margin_m"] == pytest.approx(exp["margin_m"], rel=0, abs=1e-9), got["name"]
