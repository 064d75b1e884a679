"""Robot spec files (regrasp.robot/1): a humanoid made up here, planned end to end; bad files name the field."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from planner.robot.spec_file import RobotSpecError, derive

from .robot_checks import assert_the_gate_passes
from .small_humanoid import write_small_humanoid


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "cache"))


def test_derivation_creates_the_frames_in_a_cache_folder_and_finds_the_chains(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    d = derive(spec_path)
    assert set(d.created_frames) == {"l_sole", "r_sole", "l_tcp", "r_tcp"}
    assert d.derived_urdf.is_relative_to(tmp_path / "cache")
    assert sorted(p.name for p in (tmp_path / "robot").iterdir()) == ["small_humanoid.urdf", "small_humanoid.yaml"]
    assert "l_sole" not in (tmp_path / "robot" / "small_humanoid.urdf").read_text()  # the robot's own file untouched
    links = {el.attrib["name"] for el in ET.parse(d.derived_urdf).getroot().findall("link")}
    assert {"l_sole", "r_tcp"} <= links
    assert d.spec.feet["left"].chain == ["l_hip_y", "l_hip_r", "l_hip_p", "l_knee", "l_ankle_p", "l_ankle_r"]
    assert d.spec.arms["right"].chain == ["r_sh_p", "r_sh_r", "r_sh_y", "r_elbow", "r_wr_y", "r_wr_p"]
    assert d.spec.waist == ["waist_y"] and d.spec.neck == ["neck_y"]
    assert d.limit_sources["l_knee"] == "spec effort_limits" and d.limit_sources["l_hip_y"] == "URDF <limit effort>"


def test_package_uris_resolve_with_and_without_a_host(tmp_path):
    root = tmp_path / "pkgs"
    (root / "mybot").mkdir(parents=True)
    write_small_humanoid(root / "mybot")
    for uri in ("package://mybot/small_humanoid.urdf", "package:///mybot/small_humanoid.urdf"):
        path = write_small_humanoid(tmp_path / "spec", lambda s, uri=uri: s.update(urdf=uri, packages={"mybot": str(root / "mybot")}))
        assert derive(path).urdf == (root / "mybot" / "small_humanoid.urdf").resolve()


@pytest.mark.parametrize("change, field", [
    (lambda s: s["feet"]["left"].update(link="no_such_link"), "feet.left.link"),
    (lambda s: s["hands"]["right"].update(frame="r_grip", pose_in_link=None), "hands.right.frame"),
    (lambda s: s["feet"]["right"].update(size=None), "feet.right.frame"),
    (lambda s: s["effort_limits"].update(no_such_joint=10.0), "effort_limits.no_such_joint"),
    (lambda s: s["acceleration_limits"].update(ghost_joint=1.0), "acceleration_limits.ghost_joint"),
    (lambda s: s["hands"]["left"]["jaw"].update(joints=["l_jaw_gone"]), "hands.left.jaw.joints[0]"),
    (lambda s: s["feet"]["left"].update(chain=["l_hip_y"] * 6), "feet.left.chain"),
    (lambda s: s.pop("upright"), "upright"),
    (lambda s: s.update(urdf="missing.urdf"), "urdf"),
])
def test_bad_spec_files_name_the_field(tmp_path, change, field):
    with pytest.raises(RobotSpecError) as err:
        derive(write_small_humanoid(tmp_path, change))
    assert str(err.value).startswith(field), str(err.value)


def test_a_legs_chain_given_in_the_spec_sets_its_order(tmp_path):
    order = ["l_hip_p", "l_hip_r", "l_hip_y", "l_knee", "l_ankle_r", "l_ankle_p"]
    d = derive(write_small_humanoid(tmp_path, lambda s: s["feet"]["left"].update(chain=order)))
    assert d.spec.feet["left"].chain == order
    assert d.spec.feet["right"].chain == ["r_hip_y", "r_hip_r", "r_hip_p", "r_knee", "r_ankle_p", "r_ankle_r"]


def test_a_urdf_with_every_frame_is_used_as_it_is(tmp_path):
    """The derived URDF of a first derivation has every frame: a spec naming it derives nothing more."""
    first = derive(write_small_humanoid(tmp_path / "a"))
    assert not first.urdf_as_is
    again = derive(write_small_humanoid(tmp_path / "b", lambda s: s.update(urdf=str(first.derived_urdf))))
    assert again.urdf_as_is and again.created_frames == () and again.derived_urdf == first.derived_urdf
    assert again.spec.feet == first.spec.feet and again.spec.arms == first.spec.arms


def test_a_joint_without_an_effort_limit_needs_one_in_the_spec(tmp_path):
    with pytest.raises(RobotSpecError, match=r"^effort_limits\.l_elbow: .*no effort limit"):
        derive(write_small_humanoid(tmp_path, no_effort="l_elbow"))
    derive(write_small_humanoid(tmp_path, lambda s: s["effort_limits"].update(l_elbow=80.0), no_effort="l_elbow"))


def _box_task(robot: str, rigid: bool = False) -> dict:
    """The made-up robot's pick-and-place (a scenario document naming ``robot``)."""
    scenario = {
        "schema": "regrasp.scenario/1", "name": "small-humanoid-box", "robot": robot,
        "stance": "upright", "object": {"shape": "box", "size": [0.05, 0.08, 0.10], "mass_kg": 1.0},
        "start_pose": [0.38, -0.26, 0.80, 0, 0, 0, 1], "goal_pose": [0.38, -0.1, 0.80, 0, 0, 0, 1],
        "tables": [{"name": "table", "pose": [0.5, 0, 0.375, 0, 0, 0, 1], "size": [0.4, 1.2, 0.75]}],
        "threshold_m": 0.02, "hands": "right-right", "limits": {"time_s": 120, "max_iterations": 300}, "seed": 1,
    }
    if rigid:
        # a pad presses flat on one face, so fewer hand poses reach a small box than a jaw's: a wider box, nearer
        # the arm's comfortable reach
        scenario.update(object={"shape": "box", "size": [0.12, 0.16, 0.12], "mass_kg": 1.0},
                        start_pose=[0.42, -0.3, 0.85, 0, 0, 0, 1], goal_pose=[0.42, -0.15, 0.85, 0, 0, 0, 1],
                        tables=[{"name": "table", "pose": [0.52, 0, 0.395, 0, 0, 0, 1], "size": [0.52, 1.2, 0.79]}])
        scenario["limits"]["max_iterations"] = 3000
    return scenario


@pytest.mark.parametrize("rigid", [False, True], ids=["jaws", "rigid-hands"])
def test_the_made_up_robot_plans_end_to_end_by_path_and_the_checker_and_the_gate_agree(tmp_path, monkeypatch, rigid):
    from click.testing import CliRunner
    from plan_checker import check_plan

    from service.cli.main import cli

    spec_path = write_small_humanoid(tmp_path / "robot", rigid=rigid)
    scenario = _box_task("robot/small_humanoid.yaml", rigid)
    sc_path = tmp_path / "scenario.yaml"
    sc_path.write_text(yaml.safe_dump(scenario))
    out = tmp_path / "plan.json"
    res = CliRunner().invoke(cli, ["plan", str(sc_path), "--out", str(out), "--quiet"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    plan = json.loads(out.read_text())
    assert plan["status"] == "solved", plan["failure"]
    assert plan["robot"]["name"] == "small_humanoid"
    assert check_plan(plan, sample_every=5, robot_spec=str(spec_path)).errors == []
    res = CliRunner().invoke(cli, ["robot", "check", str(spec_path)], catch_exceptions=False)
    assert res.exit_code == 0 and "l_tcp" in res.output, res.output
    # the gate finds the robot by name in the configured robot folders, with its own kinematics and limits
    monkeypatch.setenv("REGRASP_ROBOT_DIRS", str(spec_path.parent))
    assert_the_gate_passes(plan)
    if rigid:
        # the object attaches at the pad's TCP: it sits on the object's surface, and nothing opens or closes
        assert "rigid hand" in res.output
        assert not any("jaw" in name for name in plan["robot"]["joint_names"])
        held = [p for p in plan["trajectory"] if p["holding"] == "right"]
        assert held, "the object is never held"


def test_a_spec_file_is_taken_by_path_on_the_command_line_and_by_name_from_the_service_folders(tmp_path, monkeypatch):
    """`--robot FILE` over a scenario's own robot, `robot urdf FILE` and `robot info FILE --json`; the service's
    workers take the robot by its name from `REGRASP_ROBOT_DIRS` (the same plan) and refuse its path."""
    import hashlib

    from click.testing import CliRunner

    from planner.errors import InputError
    from planner.jobs.entry import run_plan
    from service.cli.main import cli

    spec_path = write_small_humanoid(tmp_path / "robot")
    sc_path = tmp_path / "scenario.yaml"
    sc_path.write_text(yaml.safe_dump(_box_task("hrp5p")))
    out = tmp_path / "plan.json"
    res = CliRunner().invoke(cli, ["plan", str(sc_path), "--robot", str(spec_path), "--out", str(out), "--quiet"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    plan = json.loads(out.read_text())
    assert plan["status"] == "solved" and plan["robot"]["name"] == "small_humanoid"
    res = CliRunner().invoke(cli, ["robot", "urdf", str(spec_path)], catch_exceptions=False)
    assert res.exit_code == 0
    urdf = res.output.strip()
    assert hashlib.sha256(open(urdf, "rb").read()).hexdigest() == plan["robot"]["urdf_sha256"]
    res = CliRunner().invoke(cli, ["robot", "info", str(spec_path), "--json"], catch_exceptions=False)
    info = json.loads(res.output)
    assert info["name"] == "small_humanoid" and info["urdf_sha256"] == plan["robot"]["urdf_sha256"]
    assert info["joint_names"] == plan["robot"]["joint_names"]

    class Ctx:
        def progress(self, fraction: float, message: str) -> None:
            pass

        def cancelled(self) -> bool:
            return False

    from planner.jobs.request_names import registered_robots

    monkeypatch.setenv("REGRASP_ROBOT_DIRS", str(spec_path.parent))
    registered_robots.cache_clear()  # a service reads its robot folders once, at start
    try:
        by_name = run_plan({"scenario": _box_task("small_humanoid")}, Ctx())
        assert by_name["status"] == "solved" and by_name["robot"] == plan["robot"]
        assert [p["q"] for p in by_name["trajectory"]] == [p["q"] for p in plan["trajectory"]]
        with pytest.raises(InputError):
            run_plan({"scenario": _box_task(str(spec_path))}, Ctx())
    finally:
        monkeypatch.delenv("REGRASP_ROBOT_DIRS")
        registered_robots.cache_clear()


SRDF = """<robot name="small_humanoid">
  <group_state name="ready" group="all">
    <joint name="root_joint" value="0 0 0.84 0 0 0 1"/>
    <joint name="l_elbow" value="-0.7"/>
    <joint name="r_elbow" value="-0.6"/>
    <joint name="not_in_this_urdf" value="0.3"/>
  </group_state>
  <disable_collisions link1="l_arm3" link2="chest" reason="Never"/>
  <disable_collisions link1="ghost_link" link2="chest" reason="Never"/>
</robot>
"""


def test_an_srdf_gives_the_collision_matrix_and_the_default_posture(tmp_path):
    def edit(spec):
        spec.update(srdf="small_humanoid.srdf", srdf_posture="ready", disable_collisions=[["r_arm3", "chest"]])
        spec["default_posture_rad"] = {"r_elbow": -0.4}  # over the SRDF's value

    spec_path = write_small_humanoid(tmp_path / "robot", edit)
    (spec_path.parent / "small_humanoid.srdf").write_text(SRDF)
    d = derive(spec_path)
    assert d.spec.disabled_collisions == [("chest", "l_arm3"), ("chest", "r_arm3")]  # the ghost link's pair left out
    assert d.spec.default_posture_rad == {"l_elbow": -0.7, "r_elbow": -0.4}
    assert any("1 naming links the URDF lacks" in n for n in d.notes)
    from planner.robot.model import load_robot
    from planner.scene.collision import CollisionWorld

    assert {("chest", "l_arm3"), ("chest", "r_arm3")} <= CollisionWorld(load_robot(str(spec_path))).disabled


@pytest.mark.parametrize(("change", "message"), [
    (lambda s: s.update(disable_collisions=[["l_arm3", "nope"]]), "disable_collisions[0]: the URDF has no link 'nope'"),
    (lambda s: s.update(srdf_posture="ready"), "srdf_posture: names a group_state of the SRDF; give `srdf`"),
    (lambda s: s.update(srdf="small_humanoid.srdf", srdf_posture="sitting"), "srdf_posture: small_humanoid.srdf has no "
                                                                              "group_state 'sitting'; it has ready"),
])
def test_bad_srdf_fields_name_the_field(tmp_path, change, message):
    spec_path = write_small_humanoid(tmp_path / "robot", change)
    (spec_path.parent / "small_humanoid.srdf").write_text(SRDF)
    with pytest.raises(RobotSpecError) as exc:
        derive(spec_path)
    assert message in str(exc.value)


def test_collision_shapes_in_the_spec_replace_those_links_collisions(tmp_path):
    """A box, a sphere and a capsule (its cylinder and two end spheres) on two links; the other links keep theirs."""
    from planner.robot.urdf_geometry import collision_primitives

    shapes = {"l_arm6": [{"box": [0.04, 0.05, 0.06], "pose": [0, 0, -0.03, 0, 0, 0, 1]}, {"sphere": 0.02}],
              "r_arm6": [{"capsule": [0.02, 0.1], "pose": [0, 0, -0.05, 0.7071068, 0, 0, 0.7071068]}]}
    d = derive(write_small_humanoid(tmp_path, lambda s: s.update(collision=shapes)))
    prims = collision_primitives(d.derived_urdf)
    left = [(p.kind, p.dims) for p in prims if p.link == "l_arm6"]
    assert left == [("box", (0.04, 0.05, 0.06)), ("sphere", (0.02,))]
    right = [p for p in prims if p.link == "r_arm6"]
    assert [(p.kind, p.dims) for p in right] == [("cylinder", (0.02, 0.1)), ("sphere", (0.02,)), ("sphere", (0.02,))]
    # the capsule's axis is turned to the link's -y: its end spheres sit 0.05 m either side along y
    ends = sorted(p.origin[:3, 3].round(6).tolist() for p in right[1:])
    assert np.allclose(ends, [[0, -0.05, -0.05], [0, 0.05, -0.05]], atol=1e-6)
    assert [p.kind for p in prims if p.link == "chest"] == ["box"]
    assert any("shape(s) of the spec on l_arm6" in n for n in d.notes)


@pytest.mark.parametrize("shapes, message", [
    ({"l_armX": [{"sphere": 0.02}]}, "collision.l_armX: the URDF has no link 'l_armX'"),
    ({"l_arm6": [{"sphere": 0.02, "box": [0.1, 0.1, 0.1]}]}, "collision.l_arm6[0]"),
    ({"l_arm6": [{"box": [0.1, -0.1, 0.1]}]}, "collision.l_arm6[0]"),
    ({"l_arm6": [{"sphere": 0.02, "pose": [0, 0, 0, 0, 0, 0, 0]}]}, "collision.l_arm6[0]"),
    ({"l_arm6": {"sphere": 0.02}}, "collision.l_arm6: a list of shapes"),
    ("boxes", "collision: `auto` or a mapping"),
])
def test_bad_collision_shapes_name_the_entry(tmp_path, shapes, message):
    with pytest.raises(RobotSpecError) as err:
        derive(write_small_humanoid(tmp_path, lambda s: s.update(collision=shapes)))
    assert str(err.value).startswith(message), str(err.value)
