"""The derived ready posture stands the CoM over the centre of the upright stance's support polygon: a made-up
humanoid whose heavy chest sits forward and to the left, so that with straight legs its CoM is far from the
centre between its feet."""

from __future__ import annotations

import json
import re

import numpy as np
import pinocchio as pin
import pytest
import yaml
from click.testing import CliRunner

from service.cli.main import cli

from .small_humanoid import write_small_humanoid
from .test_fitted_tasks import HIGH_TABLE_TASK


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "cache"))


def _front_heavy(folder):
    """The small humanoid without a posture in its spec, its 14 kg chest's CoM 0.3 m forward, 0.06 m left."""
    spec_path = write_small_humanoid(folder, lambda s: s.pop("default_posture_rad"))
    urdf = spec_path.parent / "small_humanoid.urdf"
    text, n = re.subn(r'(<link name="chest"><inertial><origin xyz=")0 0 0.22', r"\g<1>0.3 0.06 0.22", urdf.read_text())
    assert n == 1
    urdf.write_text(text)
    return spec_path


def _com_from_centre(robot, q):  # type: ignore[no-untyped-def]
    """(CoM minus the support polygon's centre (x, y), largest sole tilt) with the pelvis upright at the spec's
    height; the soles where the posture puts them, recomputed through planner/stability."""
    from planner.stability.robot_com import robot_com
    from planner.stability.stances import base_orientation, polygon_centroid, sole_size
    from planner.stability.support_polygon import support_polygon

    base = np.array([0.0, 0.0, robot.spec.upright.pelvis_height_m, *base_orientation(robot)])
    m, d = robot.pin_model, robot.create_data()
    pin.framesForwardKinematics(m, d, robot.to_pin_q(base, q))
    soles, tilt = [], 0.0
    for foot in robot.spec.feet.values():
        M = d.oMf[robot.frame_id(foot.frame)]
        tilt = max(tilt, float(np.arccos(np.clip(M.rotation[2, 2], -1, 1))))
        soles.append((M.rotation, M.translation, *sole_size(robot, foot.frame), True))
    centre = polygon_centroid(support_polygon(soles))
    return robot_com(robot, robot.create_data(), base, q)[:2] - centre, tilt


def test_the_derived_ready_posture_stands_the_com_over_the_polygon_centre_and_plans(tmp_path):
    from planner.robot.model import load_robot
    from planner.scene.collision import CollisionWorld
    from planner.scene.scenarios import parse_scenario

    spec_path = _front_heavy(tmp_path / "robot")
    robot = load_robot(str(spec_path))
    q = robot.default_q()
    assert np.all(q >= robot.lower) and np.all(q <= robot.upper)
    legs = robot.joint_indices(robot.spec.feet["left"].chain + robot.spec.feet["right"].chain)
    straight = q.copy()
    straight[legs] = np.clip(0.0, robot.lower[legs], robot.upper[legs])
    off_before, _ = _com_from_centre(robot, straight)
    assert np.linalg.norm(off_before) > 0.025  # straight legs: the CoM is well off the centre
    off, tilt = _com_from_centre(robot, q)
    assert np.linalg.norm(off) < 0.002, off  # the derived posture: within 2 mm of the centre
    assert tilt < 1e-3  # feet flat
    assert {"l_hip_p", "l_ankle_p", "r_hip_p", "r_ankle_p"} <= set(robot.spec.default_posture_rad)
    # the hands stay clear of the body and of the task's table
    scenario = parse_scenario({**HIGH_TABLE_TASK, "robot": str(spec_path)})
    world = CollisionWorld.from_scenario(robot, scenario, None)
    assert world.check(np.array([0, 0, robot.spec.upright.pelvis_height_m, 0, 0, 0, 1.0]), q) is None
    # robot check prints it to paste; pasted into the spec, it is the posture and the task plans
    res = CliRunner().invoke(cli, ["robot", "check", str(spec_path), "--quiet"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    printed = re.search(r"ready posture: CoM ([-+.0-9]+) mm forward, ([-+.0-9]+) mm left", res.output)
    assert printed and np.hypot(float(printed[1]), float(printed[2])) < 2.0, res.output
    line = next(x for x in res.output.replace("\n", " ").split("default_posture_rad: ")[1:]).split("}")[0] + "}"
    pasted = yaml.safe_load(line)
    assert pasted == pytest.approx(robot.spec.default_posture_rad)
    spec = yaml.safe_load(spec_path.read_text())
    spec["default_posture_rad"] = pasted
    pasted_path = spec_path.with_name("pasted.yaml")
    pasted_path.write_text(yaml.safe_dump(spec))
    again = load_robot(str(pasted_path))
    assert np.linalg.norm(_com_from_centre(again, again.default_q())[0]) < 0.002
    sc_path = tmp_path / "task.yaml"
    sc_path.write_text(json.dumps({**HIGH_TABLE_TASK, "robot": str(pasted_path)}))
    out = tmp_path / "plan.json"
    res = CliRunner().invoke(cli, ["plan", str(sc_path), "--out", str(out), "--quiet"], catch_exceptions=False)
    plan = json.loads(out.read_text())
    assert plan["status"] == "solved", plan["failure"]
