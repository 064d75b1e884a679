"""Every command ends on an unknown name with exit code 2 and one error line, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: One command's start imports pinocchio and the planner: seconds on a loaded machine.
COMMAND_TIMEOUT_S = 120

SCENARIO = """schema: regrasp.scenario/1
name: t
robot: {robot}
stance: {stance}
object: {{shape: box, size: [0.2, 0.2, 0.2], mass_kg: 2}}
start_pose: [0.5, 0, 0.8, 0, 0, 0, 1]
goal_pose: [0.5, 0.2, 0.8, 0, 0, 0, 1]
tables: [{{name: t, pose: [0.5, 0, 0.35, 0, 0, 0, 1], size: [0.6, 1.0, 0.7]}}]
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("cli-names")
    out = {"nao": d / "nao.yaml", "kneeling": d / "kneeling.yaml"}
    out["nao"].write_text(SCENARIO.format(robot="nao", stance="upright"))
    out["kneeling"].write_text(SCENARIO.format(robot="hrp5p", stance="kneeling"))
    return out


CASES = [
    ("plan --scenario upright --stance kneeling --out {out}", "unknown stance 'kneeling'"),
    ("plan {nao} --out {out}", "unknown robot 'nao'"),
    ("plan {kneeling} --out {out} --quiet", "unknown stance 'kneeling'"),
    ("plan --scenario nosuch --out {out}", "unknown scenario 'nosuch'"),
    ("scenario check {nao}", "unknown robot 'nao'"),
    ("scenario check {kneeling}", "unknown stance 'kneeling'"),
    ("scenario show nosuch", "unknown scenario 'nosuch'"),
    ("survey --scenario upright --stance kneeling --states 10", "unknown stance 'kneeling'"),
    ("survey {nao} --states 10", "unknown robot 'nao'"),
    ("robot info nao", "unknown robot 'nao'"),
    ("robot urdf nao", "unknown robot 'nao'"),
    ("controller-sim --robot nao", "unknown robot 'nao'"),
    ("controller-sim --stance kneeling", "unknown stance 'kneeling'"),
]


@pytest.mark.parametrize("command, said", CASES, ids=[c for c, _ in CASES])
def test_unknown_name_exits_2_with_one_line(command: str, said: str, files: dict[str, Path], tmp_path: Path) -> None:
    argv = command.format(out=tmp_path / "plan.json", **files).split()
    done = subprocess.run([sys.executable, "-m", "service.cli.main", *argv], cwd=tmp_path, capture_output=True,
                          text=True, timeout=COMMAND_TIMEOUT_S)
    assert done.returncode == 2, (done.returncode, done.stdout[-1000:], done.stderr[-2000:])
    assert "Traceback" not in done.stderr + done.stdout
    errors = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("error:") and said in errors[0], done.stderr[-2000:]
    assert not (tmp_path / "plan.json").exists()


def test_scenario_show_names_registered_meshes_so_its_output_works_anywhere(tmp_path: Path) -> None:
    import yaml

    shown = subprocess.run([sys.executable, "-m", "service.cli.main", "scenario", "show", "upright"], cwd=ROOT,
                           capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S, check=True).stdout
    doc = yaml.safe_load(shown)
    assert doc["object"]["mesh"] == {"name": "carrier_px", "scale": 1.0}
    (tmp_path / "elsewhere.yaml").write_text(shown)
    done = subprocess.run([sys.executable, "-m", "service.cli.main", "scenario", "check", "elsewhere.yaml"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
