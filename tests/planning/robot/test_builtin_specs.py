"""The built-in robots are robot spec files (regrasp.robot/1); their URDFs have every frame the specs name, so
nothing is created or derived and the planner loads the shipped URDF itself (its SHA-256 is the plans')."""

from __future__ import annotations

import hashlib

import pytest
import yaml
from click.testing import CliRunner

import robot_data
from planner.robot.registry import load_spec, urdf_path, urdf_sha256
from planner.robot.spec_file import derive

from service.cli.main import cli

BUILTINS = ("hrp5p", "jvrc1")


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "cache"))


def test_every_shipped_robot_is_a_spec_file():
    files = sorted(robot_data.data_dir().glob("*.yaml"))
    assert {p.stem for p in files} >= set(BUILTINS)
    for path in files:
        assert yaml.safe_load(path.read_text())["schema"] == "regrasp.robot/1", path.name


@pytest.mark.parametrize("name", BUILTINS)
def test_a_builtin_is_used_with_its_own_urdf_and_nothing_is_created(name, tmp_path):
    path = robot_data.data_dir() / f"{name}.yaml"
    d = derive(path)
    own = (robot_data.data_dir() / f"{name}.urdf").resolve()
    assert d.created_frames == () and d.urdf_as_is
    assert d.urdf == own and d.derived_urdf == own
    assert not (tmp_path / "cache").exists()  # nothing written to the cache folder
    assert urdf_path(name) == own
    assert urdf_sha256(name) == hashlib.sha256(own.read_bytes()).hexdigest()
    assert load_spec(name).urdf == str(own)


@pytest.mark.parametrize("name", BUILTINS)
def test_robot_check_on_a_builtin_file_says_nothing_is_created(name, monkeypatch):
    monkeypatch.chdir(robot_data.data_dir().parent)
    res = CliRunner().invoke(cli, ["robot", "check", f"{robot_data.data_dir().name}/{name}.yaml"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert f"{name}: valid" in res.output
    assert "frames created: none (all in the URDF)" in res.output
    assert "derived URDF: none (the URDF is used as it is)" in res.output


def test_the_specs_chains_jaws_and_limits_are_those_of_the_former_built_in_format():
    hrp = load_spec("hrp5p")
    assert hrp.root_link == "PELVIS"
    assert hrp.feet["left"].chain == ["LCY", "LCR", "LCP", "LKP", "LAP", "LAR"]
    assert hrp.arms["right"].chain == ["RSC", "RSP", "RSR", "RSY", "REP", "RWRY", "RWRR", "RWRP", "RHDY"]
    assert hrp.waist == ["WP", "WR", "WY"] and hrp.neck == ["HY", "HP"]
    g = hrp.arms["left"].gripper
    assert (g.joint, g.opening_per_unit, g.max_opening_m, g.closed_value) == ("LJAW", 2.0, 0.082, 0.0)
    legs = {j for f in hrp.feet.values() for j in f.chain}
    for joint, limit in hrp.acceleration_limits.items():
        assert limit == (1.0 if joint in legs else 0.5 if joint in ("LJAW", "RJAW") else 2.0), joint
    jv = load_spec("jvrc1")
    assert jv.root_link == "base_link"
    # the spec's leg order (yaw, roll, pitch, knee, ankle pitch, ankle roll), not the URDF's (P, R, Y, ..., AR, AP)
    assert jv.feet["right"].chain == ["R_HIP_Y", "R_HIP_R", "R_HIP_P", "R_KNEE", "R_ANKLE_P", "R_ANKLE_R"]
    assert jv.waist == ["WAIST_Y", "WAIST_P", "WAIST_R"] and jv.neck == ["NECK_Y", "NECK_R", "NECK_P"]
    g = jv.arms["right"].gripper
    assert (g.joint, g.opening_per_unit, g.max_opening_m, g.closed_value) == ("R_JAW", 1.0, 0.011, 0.0)
    assert jv.grip is None and jv.effort_limits == {}
