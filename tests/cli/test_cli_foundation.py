"""The foundation's command line: robot list/urdf/info, scenario checks, the demo's first step."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from service.cli.main import cli


def run(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def test_robot_list_and_urdf():
    res = run("robot", "list")
    assert res.exit_code == 0 and "hrp5p" in res.output
    res = run("robot", "urdf", "hrp5p")
    path = Path(res.output.strip())
    assert path.is_absolute() and path.is_file() and path.suffix == ".urdf"


def test_robot_info_json_follows_the_contract():
    res = run("robot", "info", "hrp5p", "--json")
    assert res.exit_code == 0
    doc = json.loads(res.output)
    for key in ("name", "urdf", "urdf_sha256", "total_mass_kg", "height_m", "joint_names", "acceleration_limits", "stances"):
        assert key in doc
    assert len(doc["joint_names"]) == 37
    assert set(doc["acceleration_limits"]) == set(doc["joint_names"])
    names = [s["name"] for s in doc["stances"]]
    assert names == ["upright", "staggered", "crouched", "one-legged"]
    for s in doc["stances"]:
        assert len(s["base_pose"]) == 7 and len(s["q"]) == 37


def test_unknown_robot_is_a_usage_error():
    res = CliRunner().invoke(cli, ["robot", "info", "hrp6"])
    assert res.exit_code == 2
    assert "valid robots" in res.output


def test_scenario_check_rejects_bad_input(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "schema: regrasp.scenario/1\nname: bad\nobject: {shape: box, size: [0.1, 0.1, 0.1], mass_kg: -3}\n"
        "start_pose: [0, 0, .nan, 0, 0, 0, 1]\ngoal_pose: [0, 0, 0, 0, 0, 0, 1]\n"
        "tables: [{name: t, pose: [0.5, 0, 0.4, 0, 0, 0, 1], size: [0.5, 1, 0.8]}]\n"
    )
    res = CliRunner().invoke(cli, ["scenario", "check", str(bad)])
    assert res.exit_code == 2
    assert "object.mass_kg" in res.output and "start_pose" in res.output
    malformed = tmp_path / "m.yaml"
    malformed.write_text("name: [unclosed\n")
    res = CliRunner().invoke(cli, ["scenario", "check", str(malformed)])
    assert res.exit_code == 2 and "malformed" in res.output


def test_threshold_beyond_the_polygon_is_reported(tmp_path):
    doc = (
        "schema: regrasp.scenario/1\nname: wide\nstance: one-legged\n"
        "object: {shape: box, size: [0.05, 0.05, 0.2], mass_kg: 1}\n"
        "start_pose: [0.45, -0.2, 0.85, 0, 0, 0, 1]\ngoal_pose: [0.45, 0.2, 0.85, 0, 0, 0, 1]\n"
        "tables: [{name: t, pose: [0.55, 0, 0.375, 0, 0, 0, 1], size: [0.4, 1.2, 0.75]}]\nthreshold_m: 0.07\n"
    )
    path = tmp_path / "wide.yaml"
    path.write_text(doc)
    res = CliRunner().invoke(cli, ["scenario", "check", str(path)])
    assert res.exit_code == 1
    assert "larger than the support polygon's inradius 65.0 mm" in res.output


@pytest.fixture(scope="module")
def demo_stances(tmp_path_factory):
    """One ``regrasp demo --stances-only`` run (it solves and draws every stance): its output folder and result."""
    out = tmp_path_factory.mktemp("demo")
    return out, run("demo", "--out", str(out), "--robot", "hrp5p", "--stances-only")


def test_demo_writes_one_picture_per_stance(demo_stances):
    out, res = demo_stances
    assert res.exit_code == 0, res.output
    for name in ("upright", "staggered", "crouched", "one-legged"):
        png = out / f"stance-{name}.png"
        assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert str(png) in res.output.replace("\n", "")


def test_demo_stance_step_prints_the_recomputed_com_and_margin(tmp_path, demo_stances):
    """Step 1 of the demo: each stance's CoM (pinocchio) and margin (shapely) as printed."""
    import numpy as np
    from shapely.geometry import Point, Polygon

    from planner.robot.model import load_robot
    from planner.stability.robot_com import robot_com as center_of_mass
    from planner.stability.stances import solve_stance
    from service.cli.demo import stance_step

    robot = load_robot("hrp5p")
    rows = stance_step(tmp_path, "hrp5p")
    _, res = demo_stances
    assert res.exit_code == 0, res.output
    for row in rows:
        st = solve_stance(robot, row["stance"])
        com = center_of_mass(robot, robot.create_data(), st.base_pose, st.q)
        assert np.allclose(row["com"], com, atol=1e-9)
        poly = Polygon(row["polygon"])
        margin = poly.exterior.distance(Point(com[:2])) * (1 if poly.contains(Point(com[:2])) else -1)
        assert row["margin_m"] == pytest.approx(margin, abs=1e-9)
        assert f"{margin * 1000:.1f}" in res.output
