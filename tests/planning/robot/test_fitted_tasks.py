"""A ready posture derived when the spec gives none, and the built-in tasks fitted to the robot that runs them
(`plan --scenario upright --robot ...`): TALOS, G1 and a made-up small humanoid."""

from __future__ import annotations

import json
import re

import numpy as np
import pinocchio as pin
import pytest
from click.testing import CliRunner

from service.cli.main import cli

from .small_humanoid import write_small_humanoid


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "cache"))


def _arms_ahead(folder):
    """The small humanoid with its shoulders mounted pitched 1 rad forward and no posture in its spec: at zero its
    arms reach 0.55 m ahead, down to 0.95 m, through a table whose top is there."""
    spec_path = write_small_humanoid(folder, lambda s: s.pop("default_posture_rad"))
    urdf = spec_path.parent / "small_humanoid.urdf"
    urdf.write_text(re.sub(r'(<joint name="[lr]_sh_p" type="revolute">.*?<origin xyz="[^"]*")', r'\1 rpy="0 -1.0 0"',
                           urdf.read_text()))
    return spec_path


HIGH_TABLE_TASK = {
    "schema": "regrasp.scenario/1", "name": "high-table", "stance": "upright",
    "object": {"shape": "box", "size": [0.05, 0.08, 0.10], "mass_kg": 0.5},
    "start_pose": [0.40, -0.26, 1.0, 0, 0, 0, 1], "goal_pose": [0.40, -0.12, 1.0, 0, 0, 0, 1],
    "tables": [{"name": "table", "pose": [0.55, 0, 0.925, 0, 0, 0, 1], "size": [0.4, 1.2, 0.05]}],
    "threshold_m": 0.02, "hands": "right-right", "limits": {"max_iterations": 400}, "seed": 1,
}


def test_a_zero_posture_with_the_arms_through_the_table_gets_a_derived_ready_posture_that_plans(tmp_path):
    from planner.robot.model import load_robot
    from planner.scene.collision import CollisionWorld
    from planner.scene.scenarios import parse_scenario

    spec_path = _arms_ahead(tmp_path / "robot")
    robot = load_robot(str(spec_path))
    posture = robot.spec.default_posture_rad
    assert {"l_sh_p", "r_sh_p", "l_jaw", "r_jaw"} <= set(posture)
    q = robot.default_q()
    assert np.all(q >= robot.lower) and np.all(q <= robot.upper)
    scenario = parse_scenario({**HIGH_TABLE_TASK, "robot": str(spec_path)})
    world = CollisionWorld.from_scenario(robot, scenario, None)
    base = np.array([0, 0, 0.84, 0, 0, 0, 1.0])
    zero = np.clip(np.zeros(robot.nq), robot.lower, robot.upper)
    hit = world.check(base, zero)
    assert hit is not None and hit.kind == "env"  # the zero posture's arms are in the table
    assert world.check(base, q) is None
    m, d = robot.pin_model, robot.create_data()
    pin.framesForwardKinematics(m, d, robot.to_pin_q(base, q))
    for side in ("l", "r"):
        tcp, shoulder = d.oMf[m.getFrameId(f"{side}_tcp")].translation, d.oMi[m.getJointId(f"{side}_sh_p")].translation
        assert shoulder[2] - tcp[2] > 0.3 and tcp[0] - shoulder[0] < 0.17  # down, not ahead
    # robot check prints it to paste into the spec, and it plans
    res = CliRunner().invoke(cli, ["robot", "check", str(spec_path), "--quiet"], catch_exceptions=False)
    assert res.exit_code == 0 and "default_posture_rad: {" in res.output and "l_sh_p: " in res.output, res.output
    sc_path = tmp_path / "task.yaml"
    sc_path.write_text(json.dumps({**HIGH_TABLE_TASK, "robot": str(spec_path)}))
    out = tmp_path / "plan.json"
    res = CliRunner().invoke(cli, ["plan", str(sc_path), "--out", str(out), "--quiet"], catch_exceptions=False)
    plan = json.loads(out.read_text())
    assert plan["status"] == "solved", plan["failure"]
    arms = robot.joint_indices(robot.spec.arms["left"].chain + robot.spec.arms["right"].chain)
    assert np.asarray(plan["trajectory"][0]["q"])[arms] == pytest.approx(q[arms], abs=1e-9)  # it starts there


def _fitted_plan(tmp_path, robot: str, hands: str, *extra: str) -> dict:
    out = tmp_path / f"plan-{len(extra)}.json"
    res = CliRunner().invoke(cli, ["plan", "--scenario", "upright", "--robot", robot, "--hands", hands, "--out",
                                   str(out), "--quiet", *extra], catch_exceptions=False)
    assert res.exit_code in (0, 1), res.output
    return json.loads(out.read_text())


def _within_reach(plan: dict) -> None:
    """The fitted task: the object starts and ends on the table, within the arm's reach of a shoulder."""
    fitted = plan["scenario"]["fitted"]
    reach = fitted["dimensions"]["reach_m"]
    for pose in (plan["object"]["start_pose"], plan["object"]["goal_pose"]):
        assert np.hypot(pose[0], abs(pose[1]) - fitted["dimensions"]["shoulder_width_m"] / 2) < reach
    table = plan["scenario"]["tables"][0]
    assert table["pose"][0] - table["size"][0] / 2 > fitted["dimensions"]["hands_forward_m"]


@pytest.mark.parametrize("robot", ["talos", "g1"])
def test_the_upright_task_fitted_to_talos_and_g1_is_within_reach_and_plans(tmp_path, robot):
    pytest.importorskip("cmeel", reason="TALOS and G1 need the example-robot-data package (the `talos` extra)")
    plan = _fitted_plan(tmp_path, robot, "left-left")
    assert plan["scenario"]["fitted"]["robot"] == robot and plan["scenario"]["fitted"]["from_robot"] == "hrp5p"
    _within_reach(plan)
    assert plan["object"]["mass_kg"] == plan["scenario"]["fitted"]["mass_kg"] < 8.0
    assert plan["status"] == "solved", plan["failure"]


def test_the_upright_task_fitted_to_a_made_up_small_humanoid_plans_and_mass_kg_overrides(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    plan = _fitted_plan(tmp_path, str(spec_path), "right-right")
    fitted = plan["scenario"]["fitted"]
    assert fitted["robot"] == "small_humanoid" and fitted["scale"] < 1.0
    _within_reach(plan)
    assert plan["status"] == "solved", plan["failure"]
    lighter = _fitted_plan(tmp_path, str(spec_path), "right-right", "--mass-kg", "0.3")
    assert lighter["object"]["mass_kg"] == 0.3 and lighter["scenario"]["fitted"] == fitted


def test_hrp5p_runs_the_built_in_task_as_written(tmp_path):
    from planner.scene.scenarios import load_builtin
    from planner.scene.task_fitting import fit_to_robot

    upright = load_builtin("upright")
    assert fit_to_robot(upright, "hrp5p") is upright
    res = CliRunner().invoke(cli, ["plan", "--scenario", "upright", "--mass-kg", "nan", "--out",
                                   str(tmp_path / "p.json"), "--quiet"])
    assert res.exit_code == 2 and "mass_kg" in res.output, res.output


def test_a_survey_of_a_built_in_task_with_another_robot_is_fitted_as_the_plan_is(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    res = CliRunner().invoke(cli, ["survey", "--scenario", "upright", "--robot", str(spec_path), "--until", "states",
                                   "--states", "20", "--seeds-min", "1", "--seeds-max", "1", "--json"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    survey = json.loads(res.output)
    plan = _fitted_plan(tmp_path, str(spec_path), "right-right")
    assert survey["object"]["mass_kg"] == plan["object"]["mass_kg"] < 8.0
    assert survey["object"]["start_pose"] == plan["object"]["start_pose"]
