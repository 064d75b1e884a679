"""Bringing one's own humanoid: a computed self-collision matrix (no SRDF), the spec's feet over the URDF's frames,
and `robot check` saying what it found. Made-up robots written here (tests/planning/robot/small_humanoid.py)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner

from service.cli.main import cli

from .small_humanoid import write_small_humanoid


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "cache"))


def _forearm_housing(spec_path) -> None:
    """The forearm's box reaches 10 mm above the elbow (a fitted box over-covering its housing): it overlaps the
    upper arm's box once the elbow bends past 0.45 rad, where the real links would not touch."""
    urdf = spec_path.parent / "small_humanoid.urdf"
    text = urdf.read_text()
    for side in "lr":
        text = re.sub(rf'(<link name="{side}_arm5">.*?<collision>)<origin xyz="[^"]*"/><geometry><box size="[^"]*"/>',
                      r'\g<1><origin xyz="0 0 -0.105"/><geometry><box size="0.06 0.06 0.23"/>', text, count=1,
                      flags=re.S)
    urdf.write_text(text)


def test_without_an_srdf_overlapping_boxes_of_neighbouring_links_are_no_self_collision_and_the_matrix_is_cached(
        tmp_path):
    from planner.robot.model import load_robot
    from planner.scene import collision_matrix
    from planner.scene.collision import CollisionWorld

    # the ready posture's elbows nearly straight: the pair does not touch there, so only the matrix can disable it
    spec_path = write_small_humanoid(tmp_path / "robot",
                                     lambda s: s["default_posture_rad"].update(l_elbow=-0.2, r_elbow=-0.2))
    _forearm_housing(spec_path)
    robot = load_robot(str(spec_path))
    world = CollisionWorld(robot)
    base = np.array([0, 0, 0.84, 0, 0, 0, 1.0])
    q = robot.default_q()
    q[robot.joint_index("l_elbow")] = -1.0
    # the boxes do overlap at that elbow angle ...
    bodies = world.bodies[: world.n_robot]
    ia = np.array([i for i, b in enumerate(bodies) if b.link == "l_arm3"])
    ib = np.array([i for i, b in enumerate(bodies) if b.link == "l_arm5"])
    Rw, pw = world._robot_world(*world.kin.forward(base, q[None, :]))
    assert world._pair_hits(Rw, pw, ia, ib, np.zeros(ia.size)).any()
    # ... in most configurations but not nearly all (so "always in collision" alone would keep checking it) ...
    matrix, cached = collision_matrix.cached_matrix(world)
    assert cached  # the world computed it first and stored it
    assert ("l_arm3", "l_arm5") in matrix.nested and ("l_arm3", "l_arm5") not in matrix.always
    # ... and the world does not call it a collision; the arm folded onto the chest still is one
    assert world.check(base, q) is None
    files = list((tmp_path / "cache" / "robots" / "collision-matrices").glob("small_humanoid-*.json"))
    assert len(files) == 1
    res = CliRunner().invoke(cli, ["robot", "check", str(spec_path), "--quiet"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "(cached)" in res.output and "l_arm3/l_arm5" in res.output
    assert "in collision at the ready posture: none" in res.output
    # the arm swung into the chest is still a collision (chest vs upper arm is checked)
    q2 = robot.default_q()
    q2[robot.joint_index("l_sh_r")] = -1.2
    hit = world.check(base, q2)
    assert hit is not None and hit.kind == "self"


def test_the_matrix_is_the_same_every_time_and_spares_the_arm_against_the_body(tmp_path):
    """Seeded: computed twice (no cache), the same pairs; the chest and an upper arm, which collide in some
    configurations, are never disabled."""
    from planner.robot.model import load_robot
    from planner.scene.collision import CollisionWorld
    from planner.scene.collision_matrix import compute_matrix

    robot = load_robot(str(write_small_humanoid(tmp_path / "robot")))
    world = CollisionWorld(robot)
    first, second = compute_matrix(world), compute_matrix(world)
    assert first == second
    assert ("chest", "l_arm3") not in first.disabled() and ("chest", "r_arm3") not in first.disabled()
    assert first.never and first.adjacent


def _sole_frames_at_the_ankles(spec_path) -> None:
    """The URDF gets its own l_sole / r_sole: plain frames at the ankle joints, 0.1 x 0.1 m boxes."""
    urdf = spec_path.parent / "small_humanoid.urdf"
    extra = "".join(
        f'<link name="{s}_sole"><collision><geometry><box size="0.1 0.1 0.02"/></geometry></collision></link>'
        f'<joint name="{s}_sole_joint" type="fixed"><parent link="{s}_leg6"/><child link="{s}_sole"/>'
        f'<origin xyz="0 0 -0.08"/></joint>' for s in "lr")
    urdf.write_text(urdf.read_text().replace("</robot>", extra + "</robot>"))


def test_the_specs_feet_win_over_the_urdfs_sole_frames(tmp_path):
    """The URDF's soles sit under the ankles; the spec puts them 60 mm forward and 0.22 x 0.12 m: the stance's
    polygon and the sole frames follow the spec, and `robot check` says so."""
    import pinocchio as pin

    from planner.robot.model import frame_poses, load_robot
    from planner.stability.stances import solve_stance

    forward = [0.06, 0, -0.08, 0, 0, 0, 1]
    spec_path = write_small_humanoid(tmp_path / "robot",
                                     lambda s: [f.update(pose_in_link=forward) for f in s["feet"].values()])
    _sole_frames_at_the_ankles(spec_path)
    robot = load_robot(str(spec_path))
    stance = solve_stance(robot, "upright")
    data = robot.create_data()
    ankle, sole = frame_poses(robot, data, stance.base_pose, stance.q, ["l_leg6", "l_sole"])
    assert np.allclose((ankle.inverse() * sole).translation, forward[:3], atol=1e-9)
    xs, ys = stance.polygon.vertices[:, 0], stance.polygon.vertices[:, 1]
    assert np.isclose(xs.max() - xs.min(), 0.22, atol=1e-6) and np.isclose(ys.max() - ys.min(), 0.2 + 0.12, atol=1e-6)
    # the ankles stand 60 mm behind the sole centres
    assert np.isclose(ankle.translation[0], -0.06, atol=1e-6)
    res = CliRunner().invoke(cli, ["robot", "check", str(spec_path), "--quiet", "--plot", str(tmp_path / "feet.png")],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "the URDF's 'l_sole' (on l_leg6) is moved to the spec's pose_in_link" in res.output
    assert (tmp_path / "feet.png").stat().st_size > 10_000
    del pin


def test_a_sole_frame_the_spec_cannot_move_is_refused_saying_how_to_fix_it(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot",
                                     lambda s: s["feet"]["left"].update(pose_in_link=[0.06, 0, -0.08, 0, 0, 0, 1]))
    _sole_frames_at_the_ankles(spec_path)
    urdf = spec_path.parent / "small_humanoid.urdf"
    # something hangs off the URDF's l_sole: it is not a plain frame
    urdf.write_text(urdf.read_text().replace("</robot>", '<link name="toe"/><joint name="toe_joint" type="fixed">'
                                             '<parent link="l_sole"/><child link="toe"/></joint></robot>'))
    res = CliRunner().invoke(cli, ["robot", "check", str(spec_path), "--quiet"])
    assert res.exit_code == 2, res.output
    assert "feet.left.frame: the URDF already has a link 'l_sole' that is not a plain frame" in res.output
    assert "drop pose_in_link" in res.output


def test_scenario_check_takes_a_robot_spec_file_as_plan_does(tmp_path):
    import yaml

    write_small_humanoid(tmp_path / "robot")
    scenario = {
        "schema": "regrasp.scenario/1", "name": "small-box", "robot": "robot/small_humanoid.yaml", "stance": "upright",
        "object": {"shape": "box", "size": [0.05, 0.08, 0.10], "mass_kg": 1.0},
        "start_pose": [0.38, -0.26, 0.80, 0, 0, 0, 1], "goal_pose": [0.38, -0.1, 0.80, 0, 0, 0, 1],
        "tables": [{"name": "table", "pose": [0.5, 0, 0.375, 0, 0, 0, 1], "size": [0.4, 1.2, 0.75]}],
        "threshold_m": 0.02,
    }
    path = tmp_path / "task.yaml"
    path.write_text(yaml.safe_dump(scenario))
    res = CliRunner().invoke(cli, ["scenario", "check", str(path)], catch_exceptions=False)
    assert res.exit_code == 0 and "is valid" in res.output, res.output
    path.write_text(yaml.safe_dump({**scenario, "robot": "robot/missing.yaml"}))
    res = CliRunner().invoke(cli, ["scenario", "check", str(path)])
    assert res.exit_code == 2 and "cannot read robot spec" in res.output, res.output


def test_robot_check_shows_progress_and_caches_what_it_fits(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    first = CliRunner().invoke(cli, ["robot", "check", str(spec_path)], catch_exceptions=False)
    assert first.exit_code == 0, first.output
    assert "reading the spec and its URDF" in first.output and "collision matrix: 2000/2000" in first.output
    again = CliRunner().invoke(cli, ["robot", "check", str(spec_path)], catch_exceptions=False)
    assert "(cached)" in again.output and "collision matrix: 2000/2000" not in again.output
