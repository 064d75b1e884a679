"""The gate's torque and grip checks: its own computation agrees with the planner's, and it vetoes."""

from __future__ import annotations

import numpy as np
import pytest

from robot_bridge.gate import GateSettings, SafetyGate
from robot_bridge.gate_effort import EffortVeto, check_effort_and_grip, static_torques
from robot_bridge.robot_files import robot_files
from robot_bridge.urdf_kinematics import load_urdf, quaternion_matrix
from schemas.policy import SafetyPolicy

from .plans import build_plan

#: The torque and grip checks on plans made at any threshold (the policy's floor is tested in test_gate_policy).
NO_FLOOR = SafetyPolicy(margin_floor_m=0.0)


@pytest.mark.parametrize("robot_name", ["hrp5p", "jvrc1"])
@pytest.mark.parametrize("stance_name", ["upright", "one-legged"])
@pytest.mark.parametrize("holding", ["none", "left", "both"])
def test_gate_torques_agree_with_the_planners(robot_name, stance_name, holding):
    from planner.robot.model import load_robot
    from planner.stability.effort import EffortEvaluator
    from planner.stability.stances import solve_stance

    robot = load_robot(robot_name)
    stance = solve_stance(robot, stance_name)
    com_local = np.array([0.02, 0.01, 0.07])
    ev = EffortEvaluator(robot, stance, 7.0, com_local)
    rng = np.random.default_rng(3)
    Q = np.repeat(stance.q[None], 8, axis=0)
    moving = np.concatenate([robot.waist_indices(), robot.arm_indices("left"), robot.arm_indices("right")])
    Q[:, moving] += rng.uniform(-0.3, 0.3, (8, moving.size))
    T_tcp_obj = np.eye(4)
    T_tcp_obj[:3, 3] = [0.0, 0.0, 0.06]
    mine = ev.evaluate(Q, holding, T_tcp_obj=T_tcp_obj)

    files = robot_files(robot_name)
    model = load_urdf(str(files.urdf))
    hands = {"none": (), "left": ("left",), "both": ("left", "right")}[holding]
    tcp = {s: files.spec["hands"][s]["frame"] for s in ("left", "right")}
    soles = [f.frame for f in stance.feet if f.in_contact]
    # the object's CoM from the gate's own frames
    _, frames = static_torques(model, robot.joint_names, Q, stance.base_pose, [()] * len(Q), np.zeros((len(Q), 3)),
                               0.0, tcp, soles, 9.81)
    Rt, pt = frames[tcp["left"]]
    c_obj = pt + Rt @ (T_tcp_obj[:3, 3] + com_local)
    torques, _ = static_torques(model, robot.joint_names, Q, stance.base_pose, [hands] * len(Q), c_obj, 7.0, tcp, soles,
                                9.81)
    for k, name in enumerate(ev.table.checked):
        np.testing.assert_allclose(torques[name], mine.torque[:, k], atol=1e-6, rtol=0, err_msg=name)


def test_a_plan_over_a_joint_limit_is_vetoed_at_its_first_point_and_passes_with_limits_off(monkeypatch):
    # 10 kg lifted forward by the right arm against a shoulder limited to 60 N*m (a weaker robot's spec).
    import robot_bridge.gate as gate_module
    from robot_bridge.robot_files import RobotFiles

    files = robot_files("hrp5p")
    weak = RobotFiles(name="hrp5p", urdf=files.urdf,
                      spec={**files.spec, "effort_limits": {**files.spec["effort_limits"], "RSP": 60.0}})
    monkeypatch.setattr(gate_module, "robot_files", lambda name, urdf_sha256=None: weak)
    plan = build_plan({"RSP": -0.6}, duration_s=2.0, mass_kg=10.0, holding="right", threshold_m=0.0,
                      com_local=(0.0, 0.0, 0.0))
    v = SafetyGate(policy=NO_FLOOR).check(plan, offline=True)
    assert not v.passed and v.check == "effort", v.message
    assert v.point_index is not None and v.point_index > 0 and "RSP" in v.message
    # the points before the veto are within the limit, the vetoed one is over it
    traj = plan["trajectory"]
    model = load_urdf(str(files.urdf))
    tcp = {"left": "l_tcp", "right": "r_tcp"}
    poses = np.array([p["object_pose"] for p in traj])
    torques, _ = static_torques(model, tuple(plan["robot"]["joint_names"]), np.array([p["q"] for p in traj]),
                                np.array(plan["stance"]["base_pose"]), [("right",)] * len(traj), poses[:, :3], 10.0,
                                tcp, ["r_sole", "l_sole"], 9.81)
    over = np.flatnonzero(np.abs(torques["RSP"]) > 60.0 * (1 + 1e-6))
    assert over[0] == v.point_index
    assert SafetyGate(GateSettings(check_limits=False), policy=NO_FLOOR).check(plan, offline=True).passed
    assert SafetyGate(policy=NO_FLOOR).check(plan, offline=True).check == "effort"


def test_a_grip_whose_moment_is_too_large_is_vetoed():
    # 10 kg whose CoM is 25 cm out along the approach axis: the wrist holds it, the jaws' friction does not.
    plan = build_plan({"RSP": -0.2}, duration_s=1.0, mass_kg=10.0, holding="right", threshold_m=0.0,
                      com_local=(0.0, 0.0, 0.25))
    files = robot_files("hrp5p")
    model = load_urdf(str(files.urdf))
    traj = plan["trajectory"]
    args = (model, files.spec, tuple(plan["robot"]["joint_names"]), np.array([p["q"] for p in traj]),
            np.array(plan["stance"]["base_pose"]), np.full(len(traj), 2), np.array([p["object_pose"] for p in traj]),
            np.array(plan["object"]["com_local"]), 10.0, plan["stance"]["feet"], 9.81)
    with pytest.raises(EffortVeto) as err:
        check_effort_and_grip(*args)
    assert err.value.check == "grip" and "closing axis" in err.value.message
    v = SafetyGate(policy=NO_FLOOR).check(plan, offline=True)
    assert not v.passed and v.check == "grip"
    # a rigid hand (no jaws) has no grip check
    rigid = {**files.spec, "hands": {s: {**h, "jaw": None} for s, h in files.spec["hands"].items()}}
    figures = check_effort_and_grip(model, rigid, *args[2:])
    assert figures["max_grip_ratio"] == 0.0


def test_the_gate_reports_the_plans_effort_ratio():
    plan = build_plan({"RSP": -0.3}, duration_s=1.0, mass_kg=5.0, holding="right", threshold_m=0.0)
    v = SafetyGate(policy=NO_FLOOR).check(plan, offline=True)
    assert v.passed, v.message
    from planner.robot.model import load_robot
    from planner.stability.effort import EffortEvaluator
    from planner.stability.stances import solve_stance

    robot = load_robot("hrp5p")
    traj = plan["trajectory"]
    poses = np.array([p["object_pose"] for p in traj])
    T = np.zeros((len(traj), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = quaternion_matrix(poses[:, 3:]), poses[:, :3], 1.0
    ev = EffortEvaluator(robot, solve_stance(robot, "upright"), 5.0, np.array(plan["object"]["com_local"]))
    ratio = ev.evaluate(np.array([p["q"] for p in traj]), "right", object_pose=T).effort_ratio
    assert v.stats["effort"]["max_ratio"] == pytest.approx(float(ratio.max()), abs=1e-9)


def test_non_finite_torques_are_a_veto_not_a_pass():
    """A NaN joint value (the gate's finite check stops it first; this check must hold on its own) makes NaN
    torques: the effort check vetoes at that point, it never lets a NaN ratio (which compares false with
    every limit) pass."""
    from robot_bridge.robot_files import robot_files
    from robot_bridge.urdf_kinematics import load_urdf

    files = robot_files("hrp5p")
    model = load_urdf(str(files.urdf))
    n = 3
    Q = np.zeros((n, len(model.joint_names)))
    Q[1, list(model.joint_names).index("WY")] = np.nan
    pose = np.tile([0.3, -0.2, 0.9, 0.0, 0.0, 0.0, 1.0], (n, 1))
    feet = [{"frame": "l_sole", "pose": np.array([0, 0.1, 0, 0, 0, 0, 1.0]), "in_contact": True},
            {"frame": "r_sole", "pose": np.array([0, -0.1, 0, 0, 0, 0, 1.0]), "in_contact": True}]
    with np.errstate(all="ignore"), pytest.raises(EffortVeto) as err:
        check_effort_and_grip(model, files.spec, tuple(model.joint_names), Q, np.array([0, 0, 0.8, 0, 0, 0, 1.0]),
                              np.full(n, 2), pose, np.zeros(3), 2.0, feet, 9.81)
    assert err.value.check == "effort" and err.value.point == 1 and "not finite" in err.value.message


@pytest.mark.parametrize("robot_name", ["hrp5p", "jvrc1"])
def test_the_gate_reads_the_built_in_spec_files_as_the_planner_does(robot_name, tmp_path, monkeypatch):
    """The built-ins are regrasp.robot/1 files whose URDF needs nothing derived: the gate takes that URDF itself
    (no derived URDF in the cache folder needed) and the same limits, TCPs and jaws as the planner."""
    from planner.robot.model import load_robot
    from robot_bridge.gate_effort import effort_spec
    from robot_bridge.robot_files import _robot_files

    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "empty-cache"))
    _robot_files.cache_clear()
    files = robot_files(robot_name)
    robot = load_robot(robot_name)
    assert files.spec["schema"] == "regrasp.robot/1"
    assert files.urdf == robot.urdf_path and files.urdf_sha256 == robot.urdf_sha256
    assert [files.acceleration_limit(j) for j in robot.joint_names] == robot.acceleration_limit.tolist()
    spec = effort_spec(files.spec)
    assert {s: (h.tcp, h.jaws) for s, h in spec.hands.items()} == \
        {s: (a.tcp, (a.gripper.joint,)) for s, a in robot.spec.arms.items()}
    assert spec.effort_limits == robot.spec.effort_limits
    grip = robot.spec.grip
    assert all(h.grip == (None if grip is None else (grip.friction, grip.force_n, grip.patch_radius_m))
               for h in spec.hands.values())
    _robot_files.cache_clear()


def test_the_gate_takes_the_derived_urdf_of_the_plans_hash(tmp_path, monkeypatch):
    """Two derived URDFs of one robot in the cache (two spec versions): the gate reads the one whose SHA-256
    the plan names, whichever is newer; an unknown SHA-256 gets the newest (and the gate's hash check)."""
    import hashlib
    import os
    import time

    from robot_bridge import robot_files as rf

    spec = tmp_path / "specs" / "twin.yaml"
    spec.parent.mkdir()
    spec.write_text("schema: regrasp.robot/1\nname: twin\nurdf: missing.urdf\nfeet: {left: {frame: l_sole}, right: "
                    "{frame: r_sole}}\nhands: {left: {frame: l_tcp}, right: {frame: r_tcp}}\n"
                    "acceleration_limits: {default: 1.0}\n")
    cache = tmp_path / "cache"
    paths = []
    for k, text in enumerate(("<robot name='twin-a'/>", "<robot name='twin-b'/>")):
        path = cache / "robots" / f"twin-{k:016d}" / "twin.urdf"
        path.parent.mkdir(parents=True)
        path.write_text(text)
        os.utime(path, (time.time() + k, time.time() + k))  # the second is the newer
        paths.append(path)
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(cache))
    monkeypatch.setenv("REGRASP_ROBOT_DIRS", str(spec.parent))
    rf._robot_files.cache_clear()
    try:
        older = hashlib.sha256(paths[0].read_bytes()).hexdigest()
        assert rf.robot_files("twin", older).urdf == paths[0]
        assert rf.robot_files("twin", "0" * 64).urdf == paths[1]
        assert rf.robot_files("twin").urdf == paths[1]
    finally:
        rf._robot_files.cache_clear()
