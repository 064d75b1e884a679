"""`regrasp plan --speed-scale` and the scenario's `zmp_margin_m` at the command line: bad values are a usage error
(exit 2, one line saying what is wrong), a good one is recorded in the plan's timing."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "tests" / "data" / "small-box.yaml"
RUN = "import sys; from service.cli.main import main; sys.exit(main())"


def regrasp(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", RUN, *args], capture_output=True, text=True, cwd=ROOT, timeout=600)


@pytest.mark.parametrize("value", ["0", "-0.5", "1.5", "nan"])
def test_a_speed_scale_outside_0_1_is_a_usage_error(tmp_path, value):
    done = regrasp("plan", str(SMALL), "--speed-scale", value, "--out", str(tmp_path / "p.json"), "--quiet")
    assert done.returncode == 2
    assert "--speed-scale" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "p.json").exists()


def test_a_zmp_margin_below_the_safety_floor_is_a_usage_error(tmp_path):
    doc = yaml.safe_load(SMALL.read_text())
    doc["zmp_margin_m"] = 0.01  # the built-in policy's floor is 30 mm
    scenario = tmp_path / "low.yaml"
    scenario.write_text(yaml.safe_dump(doc))
    done = regrasp("plan", str(scenario), "--out", str(tmp_path / "p.json"), "--quiet")
    assert done.returncode == 2
    assert "zmp_margin_m" in done.stderr and "floor" in done.stderr and "Traceback" not in done.stderr


def test_the_speed_scale_is_recorded_and_slows_the_plan(tmp_path):
    out = tmp_path / "p.json"
    done = regrasp("plan", str(SMALL), "--speed-scale", "0.5", "--out", str(out), "--quiet")
    assert done.returncode == 0, done.stderr
    plan = json.loads(out.read_text())
    assert plan["timing"]["speed_scale"] == 0.5
    assert plan["timing"]["duration_s"] == plan["trajectory"][-1]["t"]
    assert plan["timing"]["duration_s"] > 1.8 * plan["timing"]["time_optimal_duration_s"]
