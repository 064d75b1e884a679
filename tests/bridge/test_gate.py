"""The safety gate: an independent channel that agrees with the planner, and every check's veto."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

from robot_bridge.gate import Approval, GateSettings, MeasuredState, SafetyGate
from schemas.plan import plan_sha256
from schemas.policy import SafetyPolicy

from .conftest import REPO
from .plans import build_plan, edited, stance_state, true_min_margin


@pytest.fixture(scope="module")
def gate() -> SafetyGate:
    """The gate's checks at any threshold: a policy with no floor (the floor's own tests are in test_gate_policy)."""
    return SafetyGate(policy=SafetyPolicy(margin_floor_m=0.0))


@pytest.fixture(scope="module")
def plan() -> dict:
    return build_plan({"RSP": -0.3}, duration_s=1.0, threshold_m=0.02)


def online(gate: SafetyGate, plan: dict, **kw):
    names, q, _ = stance_state()
    approval = kw.pop("approval", Approval(plan_sha256(plan), datetime.now(timezone.utc) + timedelta(minutes=5)))
    return gate.check(plan, approval=approval, measured=kw.pop("measured", MeasuredState(names, q)), **kw)


def test_gate_imports_neither_planner_nor_pinocchio():
    code = (
        "import sys, robot_bridge.gate, robot_bridge.dispatcher, robot_bridge.controller_sim\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('planner', 'pinocchio'))\n"
        "print(bad); sys.exit(1 if bad else 0)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, f"the gate pulled in {out.stdout} {out.stderr}"


@pytest.mark.parametrize("robot_name", ["hrp5p", "jvrc1"])
def test_gate_kinematics_agree_with_planner_and_pinocchio(robot_name):
    import pinocchio as pin

    from planner.kinematics.batch import BatchKinematics
    from planner.robot.model import frame_poses, load_robot
    from robot_bridge.robot_files import robot_files
    from robot_bridge.urdf_kinematics import BatchFK, load_urdf

    robot = load_robot(robot_name)
    rng = np.random.default_rng(7)
    n = 200
    lo, hi = np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi)
    Q = rng.uniform(lo, hi, size=(n, robot.nq))
    held = rng.choice(robot.nq, size=robot.nq // 3, replace=False)
    Q[:, held] = Q[:1, held]  # some joints hold still: the gate passes them as one value
    base = np.hstack([rng.normal(scale=0.5, size=(n, 3)), rng.normal(size=(n, 4))])
    base[:, 3:] /= np.linalg.norm(base[:, 3:], axis=1, keepdims=True)
    frames = ["l_tcp", "r_tcp", "l_sole", "r_sole"]
    # Shuffled column order: the gate maps the plan's joint names, it does not assume an order.
    perm = rng.permutation(robot.nq)
    fk = BatchFK(load_urdf(str(robot_files(robot_name).urdf)), [robot.joint_names[i] for i in perm])
    columns = [Q[:1, i] if i in held else Q[:, i] for i in perm]
    bk = BatchKinematics(robot)
    for b in (base[3], base):  # one base for all states, then one per state
        com, points = fk.com_and_points(b, columns, n, frames)
        ref_com, ref = bk.com_and_frames(b, Q, frames)
        assert np.abs(com - ref_com).max() < 1e-9
        for f in frames:
            assert np.abs(points[f] - ref[f][1]).max() < 1e-9
    data = robot.create_data()
    for k in range(0, n, 40):  # and pinocchio itself, state by state
        qp = robot.to_pin_q(base[k], Q[k])
        assert np.abs(pin.centerOfMass(robot.pin_model, data, qp) - com[k]).max() < 1e-9
        for f, M in zip(frames, frame_poses(robot, data, base[k], Q[k], frames)):
            assert np.abs(M.translation - points[f][k]).max() < 1e-9
    assert abs(fk.total_mass - robot.total_mass) < 1e-9


_ODD_URDF = """<robot name="odd">
  <link name="base"><inertial><mass value="3.0"/><origin xyz="0.01 0.02 0.03"/></inertial></link>
  <link name="a"><inertial><mass value="1.5"/><origin xyz="0.1 -0.05 0.2"/></inertial></link>
  <link name="b"><inertial><mass value="0.7"/><origin xyz="0.0 0.3 0.0"/></inertial></link>
  <link name="c"><inertial><mass value="0.4"/><origin xyz="0.05 0.0 -0.1"/></inertial></link>
  <link name="d"><inertial><mass value="0.2"/><origin xyz="0.0 0.0 0.04"/></inertial></link>
  <link name="tip"/>
  <joint name="skew" type="revolute"><parent link="base"/><child link="a"/>
    <origin xyz="0.1 0.2 0.3" rpy="0.3 -0.2 0.5"/><axis xyz="1 2 -0.5"/><limit lower="-3" upper="3" velocity="1"/></joint>
  <joint name="spin" type="continuous"><parent link="a"/><child link="b"/>
    <origin xyz="0 0 0.4" rpy="0 0.7 0"/><axis xyz="0 0 -1"/><limit velocity="1"/></joint>
  <joint name="slide" type="prismatic"><parent link="b"/><child link="c"/>
    <origin xyz="0.2 0 0" rpy="0.1 0 0"/><axis xyz="0.6 0 0.8"/><limit lower="-0.5" upper="0.5" velocity="1"/></joint>
  <joint name="follow" type="revolute"><parent link="a"/><child link="d"/>
    <origin xyz="0 -0.1 0"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" velocity="1"/>
    <mimic joint="skew" multiplier="-0.5" offset="0.25"/></joint>
  <joint name="tip_fixed" type="fixed"><parent link="c"/><child link="tip"/><origin xyz="0.05 0.01 0.02" rpy="0.2 0.3 0.4"/></joint>
</robot>
"""


def test_gate_kinematics_on_every_joint_kind_against_a_per_state_reference(tmp_path):
    """Skewed axes, continuous, prismatic, mimic with offset, rotated origins: the paths the robots above do not take."""
    from scipy.spatial.transform import Rotation

    from robot_bridge.urdf_kinematics import BatchFK, UrdfModel

    path = tmp_path / "odd.urdf"
    path.write_text(_ODD_URDF)
    model = UrdfModel.from_file(path)
    assert model.joint_names == ("skew", "spin", "slide")
    fk = BatchFK(model, ["slide", "skew", "spin"])
    rng = np.random.default_rng(11)
    n = 50
    Q = np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-3, 3, n), rng.uniform(-6, 6, n)])  # slide, skew, spin
    base = np.array([0.3, -0.2, 0.9, *Rotation.from_rotvec([0.2, -0.1, 0.4]).as_quat()])

    def reference(q: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Homogeneous transforms joint by joint, one state: (CoM, tip origin)."""
        T = {"base": np.eye(4)}
        T["base"][:3, :3] = Rotation.from_quat(base[3:]).as_matrix()
        T["base"][:3, 3] = base[:3]
        for j in model.joints:
            origin = np.eye(4)
            origin[:3, :3], origin[:3, 3] = j.origin_rot, j.origin_xyz
            motion = np.eye(4)
            value = q[j.mimic[0]] * j.mimic[1] + j.mimic[2] if j.mimic else q.get(j.name, 0.0)
            if j.type in ("revolute", "continuous"):
                motion[:3, :3] = Rotation.from_rotvec(j.axis * value).as_matrix()
            elif j.type == "prismatic":
                motion[:3, 3] = j.axis * value
            T[j.child] = T[j.parent] @ origin @ motion
        mass = sum(link.mass for link in model.links.values())
        com = sum(link.mass * (T[name][:3, :3] @ link.com_local + T[name][:3, 3]) for name, link in model.links.items())
        return com / mass, T["tip"][:3, 3], T["d"][:3, 3]

    com, points = fk.com_and_points(base, [Q[:, 0], Q[:, 1], Q[:1, 2]], n, ["tip", "d"])
    for k in range(n):
        ref_com, ref_tip, ref_d = reference({"slide": Q[k, 0], "skew": Q[k, 1], "spin": Q[0, 2]})
        assert np.abs(com[k] - ref_com).max() < 1e-12
        assert np.abs(points["tip"][k] - ref_tip).max() < 1e-12
        assert np.abs(points["d"][k] - ref_d).max() < 1e-12


def test_valid_plan_passes_every_check_online(gate, plan):
    v = online(gate, plan)
    assert v.passed, v.summary()
    assert v.skipped == []
    for check in ("approval", "plan_hash", "structure", "robot_model", "finite", "time", "start_state", "joint_position",
                  "joint_velocity", "joint_acceleration", "feet", "com_margin", "zmp"):
        assert check in v.checks_passed
    assert v.samples == (len(plan["trajectory"]) - 1) * 2 + 1  # every 5 ms sample and the midpoints
    # the gate's own margin equals the planner's
    assert v.stats["com_margin"]["min_margin_m"] == pytest.approx(true_min_margin(plan), abs=1e-9)


def test_online_requires_approval_and_state(gate, plan):
    v = gate.check(plan)
    assert not v.passed and v.check == "approval"
    v = gate.check(plan, approval=Approval(plan_sha256(plan), datetime.now(timezone.utc) + timedelta(minutes=1)))
    assert not v.passed and v.check == "start_state"


def test_expired_approval(gate, plan):
    v = online(gate, plan, approval=Approval(plan_sha256(plan), datetime.now(timezone.utc) - timedelta(seconds=1)))
    assert not v.passed and v.check == "approval" and "expired" in v.message


def test_plan_edited_after_approval(gate, plan):
    changed = edited(plan, lambda p: p["trajectory"][50]["q"].__setitem__(0, p["trajectory"][50]["q"][0] + 1e-6))
    v = online(gate, changed, approval=Approval(plan_sha256(plan), datetime.now(timezone.utc) + timedelta(minutes=1)))
    assert not v.passed and v.check == "plan_hash"


def test_nan_and_inf_are_vetoed_with_the_sample(gate, plan):
    for bad in (float("nan"), float("inf")):
        p = edited(plan, lambda p: p["trajectory"][77]["q"].__setitem__(5, bad))
        v = gate.check(p, offline=True)
        assert not v.passed and v.check == "finite"
        assert v.point_index == 77 and v.sample_index == 77 * 2
        assert "trajectory[77].q[5]" in v.message


@pytest.mark.parametrize("key,index,bad", [("q", 5, "0.1"), ("q", 0, None), ("object_pose", 2, None), ("t", None, "1.0")])
def test_values_that_are_not_json_numbers_are_vetoed_by_name(gate, plan, key, index, bad):
    """A number written as a string (or a null) is malformed, even where it would convert."""
    def spoil(p):
        pt = p["trajectory"][40]
        if index is None:
            pt[key] = bad
        else:
            pt[key][index] = bad

    v = gate.check(edited(plan, spoil), offline=True)
    assert not v.passed and v.check == "structure", v.summary()
    where = f"trajectory[40].{key}" + (f"[{index}]" if index is not None else "")
    assert f"{where} is {bad!r}, not a number" in v.message


def test_time_must_increase_strictly(gate, plan):
    p = edited(plan, lambda p: p["trajectory"][30].__setitem__("t", p["trajectory"][29]["t"]))
    v = gate.check(p, offline=True)
    assert not v.passed and v.check == "time" and v.point_index == 30


def test_start_state_mismatch(gate, plan):
    names, q, _ = stance_state()
    moved = list(q)
    moved[names.index("RSP")] += 0.05
    v = online(gate, plan, measured=MeasuredState(names, moved))
    assert not v.passed and v.check == "start_state" and "RSP" in v.message and v.sample_index == 0


def test_joint_limits(gate, plan):
    from robot_bridge.robot_files import robot_files
    from robot_bridge.urdf_kinematics import load_urdf

    model = load_urdf(str(robot_files("hrp5p").urdf))
    names = plan["robot"]["joint_names"]
    j = names.index("REP")
    upper = float(model.upper[list(model.joint_names).index("REP")])
    p = edited(plan, lambda p: [pt["q"].__setitem__(j, upper + 0.01) for pt in p["trajectory"]])
    v = gate.check(p, offline=True)
    assert not v.passed and v.check == "joint_position" and "REP" in v.message and v.point_index == 0
    # a jump of 0.01 rad in 5 ms is 2 rad/s: above the arm's 1 rad/s
    p = edited(plan, lambda p: p["trajectory"][40]["q"].__setitem__(j, p["trajectory"][40]["q"][j] + 0.01))
    v = gate.check(p, offline=True)
    assert not v.passed and v.check == "joint_velocity" and "REP" in v.message and v.point_index == 39
    # 0.0004 rad bump: 0.08 rad/s is fine, 16 rad/s^2 is not (arms: 2 rad/s^2)
    p = edited(plan, lambda p: p["trajectory"][40]["q"].__setitem__(j, p["trajectory"][40]["q"][j] + 0.0004))
    v = gate.check(p, offline=True)
    assert not v.passed and v.check == "joint_acceleration" and v.point_index == 39


def test_plan_must_start_and_end_at_rest(gate):
    p = build_plan({"RSP": -0.3}, duration_s=1.0, rest_s=0.0)
    cut = edited(p, lambda p: p.__setitem__("trajectory", p["trajectory"][:-60]))  # ends while still moving
    v = gate.check(cut, offline=True)
    assert not v.passed and v.check == "joint_acceleration" and v.point_index == len(cut["trajectory"]) - 1


def test_feet_must_stay_in_the_stance(gate):
    p = build_plan({"RKP": 0.02}, duration_s=1.0)  # a knee bends: the right sole leaves its place
    v = gate.check(p, offline=True)
    assert not v.passed and v.check == "feet" and "r_sole" in v.message


def test_com_margin_threshold_and_first_sample(gate, plan):
    true = true_min_margin(plan)
    v = gate.check(plan, offline=True, threshold_m=true + 2e-4)
    assert not v.passed and v.check == "com_margin"
    assert gate.check(plan, offline=True, threshold_m=true + 0.5e-4).passed  # within the contract's 0.1 mm tolerance
    # the first failing sample, not the worst one
    v = gate.check(plan, offline=True, threshold_m=0.5)
    assert v.sample_index == 0


def test_margin_is_recomputed_not_read_from_the_plan(gate):
    heavy = build_plan({"RSP": -1.2, "LSP": -1.2, "WP": 0.3}, duration_s=3.0, mass_kg=8.0, holding="right", threshold_m=0.0)
    assert true_min_margin(heavy) < 0
    lie = edited(heavy, lambda p: [pt.__setitem__("margin_m", 0.1) for pt in p["trajectory"]])
    v = gate.check(lie, offline=True)
    assert not v.passed and v.check == "com_margin"


def test_held_object_counts_only_while_held(gate):
    # 60 kg held far forward: only the held object makes the robot unstable.
    held = build_plan({"RSP": -0.1}, duration_s=0.5, mass_kg=60.0, holding="right", com_local=(0.0, 0.0, 0.6))
    resting = build_plan({"RSP": -0.1}, duration_s=0.5, mass_kg=60.0, holding="none", com_local=(0.0, 0.0, 0.6))
    assert true_min_margin(held) < 0.02 < true_min_margin(resting)
    assert gate.check(resting, offline=True).passed
    v = gate.check(held, offline=True)
    assert not v.passed and v.check == "com_margin"


def test_zmp_outside_polygon(gate):
    # A held object that shakes 4 mm per sample: statically fine, dynamically not.
    p = build_plan({"RSP": -0.05}, duration_s=0.5, mass_kg=10.0, holding="right")
    def shake(p):
        for i, pt in enumerate(p["trajectory"]):
            pt["object_pose"][0] += 0.002 if i % 2 else -0.002
    p = edited(p, shake)
    v = gate.check(p, offline=True)
    assert not v.passed and v.check == "zmp"


def test_structure_errors_are_named(gate, plan):
    cases = {
        "schema": edited(plan, lambda p: p.__setitem__("schema", "regrasp.plan/0")),
        "status": edited(plan, lambda p: p.__setitem__("status", "infeasible")),
        "joint": edited(plan, lambda p: p["robot"]["joint_names"].__setitem__(0, "NOPE")),
        "short q": edited(plan, lambda p: p["trajectory"][3]["q"].pop()),
        "holding": edited(plan, lambda p: p["trajectory"][3].__setitem__("holding", "tail")),
        "robot": edited(plan, lambda p: p["robot"].__setitem__("name", "r2d2")),
    }
    for what, bad in cases.items():
        v = gate.check(bad, offline=True)
        assert not v.passed and v.check in ("structure", "gate_error"), (what, v.summary())
    v = gate.check(cases["robot"], offline=True)
    assert "r2d2" in v.message and "hrp5p" in v.message
    assert gate.check("not a plan", offline=True).check == "structure"
    urdf = edited(plan, lambda p: p["robot"].__setitem__("urdf_sha256", "0" * 64))
    assert gate.check(urdf, offline=True).check == "robot_model"


def test_gate_fails_closed(gate, plan, monkeypatch):
    import robot_bridge.gate as gate_module

    def broken(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(gate_module, "support_polygon", broken)
    v = gate.check(plan, offline=True)
    assert not v.passed and v.check == "gate_error" and "disk on fire" in v.message


def test_coarser_plan_is_checked_at_the_controller_period(gate):
    coarse = _coarse(build_plan({"RSP": -0.3}, duration_s=1.0), 2)  # dt_s 10 ms
    v = gate.check(coarse, offline=True)
    assert v.passed, v.summary()
    assert v.samples == (len(coarse["trajectory"]) - 1) * 4 + 1  # 2 controller periods per point, x2 midpoints


def _coarse(plan: dict, every: int) -> dict:
    """The plan with every ``every``-th point, at dt_s = every x 5 ms: the gate then interpolates between points."""
    dt = plan["dt_s"] * every

    def cut(p: dict) -> None:
        p["trajectory"] = p["trajectory"][::every]
        p["dt_s"] = dt
        for i, pt in enumerate(p["trajectory"]):
            pt["t"] = i * dt

    return edited(plan, cut)


def _per_sample_reference(plan: dict, S: int, oversample: int) -> dict:
    """The gate's figures the plain way: one sample at a time, pinocchio FK, the planner's polygon.

    Sample g lies in interval g // S at fraction (g % S) / S; q and the object position are
    interpolated linearly, the object quaternion along the shortest way and normalised.
    """
    import pinocchio as pin
    from scipy.spatial.transform import Rotation

    from planner.robot.model import frame_poses

    from .plans import _robot_and_stance

    robot, st = _robot_and_stance(plan["robot"]["name"], plan["stance"]["name"])
    data = robot.create_data()
    traj, n = plan["trajectory"], len(plan["trajectory"])
    base = np.array(plan["stance"]["base_pose"])
    com_local = np.array(plan["object"]["com_local"])
    M, m = robot.total_mass, plan["object"]["mass_kg"]
    feet = [(f["frame"], np.array(f["pose"][:3])) for f in plan["stance"]["feet"]]
    N = (n - 1) * S + 1
    rcom, ocom, held, feet_dev = np.empty((N, 3)), np.empty((N, 3)), np.empty(N, dtype=bool), 0.0
    for g in range(N):
        i, f = min(g // S, n - 1), (g % S) / S
        a, b = traj[i], traj[min(i + 1, n - 1)]
        q = np.array(a["q"]) + f * (np.array(b["q"]) - np.array(a["q"]))
        pos = np.array(a["object_pose"][:3]) + f * (np.array(b["object_pose"][:3]) - np.array(a["object_pose"][:3]))
        qa, qb = np.array(a["object_pose"][3:]), np.array(b["object_pose"][3:])
        qb = -qb if qa @ qb < 0 else qb
        quat = qa + f * (qb - qa)
        rcom[g] = pin.centerOfMass(robot.pin_model, data, robot.to_pin_q(base, q))
        ocom[g] = pos + Rotation.from_quat(quat / np.linalg.norm(quat)).apply(com_local)
        held[g] = a["holding"] != "none"
        for (frame, placed), M_f in zip(feet, frame_poses(robot, data, base, q, [fr for fr, _ in feet])):
            feet_dev = max(feet_dev, float(np.linalg.norm(M_f.translation - placed)))

    def system(h: np.ndarray, r: np.ndarray, o: np.ndarray) -> np.ndarray:
        w = m * h[:, None]
        return (M * r + w * o) / (M + w)

    margin = st.polygon.margin(system(held, rcom, ocom)[:, :2])
    change = [i for i in range(1, n) if traj[i]["holding"] != traj[i - 1]["holding"]]
    ks = np.array(change, dtype=int) * S
    before = np.array([traj[i - 1]["holding"] != "none" for i in change], dtype=bool)
    at_change = st.polygon.margin(system(before, rcom[ks], ocom[ks])[:, :2]) if change else np.array([])
    ctrl = np.arange(0, N, oversample)
    dt = plan["dt_s"]
    c, cp, cn = (system(held[ctrl], rcom[k], ocom[k]) for k in (ctrl, np.maximum(ctrl - S, 0), np.minimum(ctrl + S, N - 1)))
    zmp = c[:, :2] - c[:, 2:3] / 9.81 * (cn[:, :2] - 2 * c[:, :2] + cp[:, :2]) / dt**2
    return {"margin": margin, "at_change": at_change, "change_samples": ks, "zmp": st.polygon.margin(zmp),
            "feet_dev": feet_dev}


def test_batched_gate_equals_a_per_sample_reference(gate):
    """Same verdicts and margins as a plain per-sample computation, on a plan the gate interpolates (dt_s 20 ms)."""
    plan = build_plan({"RSP": -0.7, "REP": -0.4, "WY": 0.25}, duration_s=1.5, mass_kg=5.0, holding="right", threshold_m=0.0)
    plan = _coarse(edited(plan, lambda p: [pt.__setitem__("holding", "none") for pt in p["trajectory"][:60]]), 4)
    S = 4 * 2  # 4 controller periods per point, and the midpoints
    ref = _per_sample_reference(plan, S, 2)
    assert ref["change_samples"].size == 1  # the grasp is one of the cases compared
    v = gate.check(plan, offline=True)
    assert v.passed, v.summary()
    assert v.samples == len(ref["margin"])
    assert v.stats["com_margin"]["min_margin_m"] == pytest.approx(ref["margin"].min(), abs=1e-9)
    assert v.stats["com_margin"]["at_sample"] == int(np.argmin(ref["margin"]))
    assert v.stats["com_margin"]["min_margin_at_holding_changes_m"] == pytest.approx(ref["at_change"].min(), abs=1e-9)
    assert v.stats["zmp"]["min_margin_m"] == pytest.approx(ref["zmp"].min(), abs=1e-9)
    assert v.stats["feet"]["max_deviation_m"] == pytest.approx(ref["feet_dev"], abs=1e-9)
    # A threshold just above the smallest margin: the veto names the reference's first failing sample.
    thr = float(ref["margin"].min()) + 3e-4
    v = gate.check(plan, offline=True, threshold_m=thr)
    failing = np.flatnonzero(ref["margin"] < thr - 1e-4)
    failing = np.union1d(failing, ref["change_samples"][ref["at_change"] < thr - 1e-4])
    assert not v.passed and v.check == "com_margin" and v.sample_index == int(failing[0])


def test_veto_at_a_release_reports_the_failing_margin(gate):
    """Releasing a heavy object at the held phase's worst posture: the 'before' mass set at the release fails
    first, and the veto reports that set's margin, not the (much larger) margin of the robot alone there."""
    plan = build_plan({"RSP": -0.9, "REP": -0.4}, duration_s=1.5, mass_kg=6.0, holding="right", threshold_m=0.0)
    release = len(plan["trajectory"]) // 2  # mid-move: the held margin still falls up to here
    plan = edited(plan, lambda p: [pt.__setitem__("holding", "none") for pt in p["trajectory"][release:]])
    ref = _per_sample_reference(plan, 2, 2)
    k, before = int(ref["change_samples"][0]), float(ref["at_change"][0])
    assert before < ref["margin"][:k].min() < ref["margin"][k:].min()
    thr = (before + float(ref["margin"][:k].min())) / 2 + 1e-4  # only the 'before' set at the release is below
    v = gate.check(plan, offline=True, threshold_m=thr)
    assert not v.passed and v.check == "com_margin" and v.sample_index == k, v.summary()
    reported = float(re.search(r"falls to (-?[\d.]+) mm", v.message).group(1)) / 1000
    assert reported == pytest.approx(before, abs=1e-5) and reported < thr


def test_zmp_is_checked_between_the_points(gate):
    """dt_s 50 ms: every point's ZMP is inside, the interpolated controller samples' is not.

    The held object turns by 1 rad about the vertical during one interval while its frame
    moves so that its CoM is the same at every point: the CoM of the points never moves,
    but between them it bulges out along the arc and back, and the ZMP (central differences
    at dt_s along the interpolated path) swings far outside.
    """
    from scipy.spatial.transform import Rotation

    base = build_plan({"RSP": 0.0}, duration_s=1.0, mass_kg=10.0, holding="right", com_local=(0.3, 0.0, 0.0),
                      threshold_m=0.0)
    plan = _coarse(base, 10)
    turn = 8  # the object turns between points 8 and 9

    def rotate(p: dict) -> None:
        first = np.array(p["trajectory"][0]["object_pose"])
        R0 = Rotation.from_quat(first[3:])
        com = first[:3] + R0.apply(p["object"]["com_local"])
        for pt in p["trajectory"][turn + 1:]:
            R = Rotation.from_rotvec([0.0, 0.0, 1.0]) * R0
            pt["object_pose"] = [*(com - R.apply(p["object"]["com_local"])), *R.as_quat()]

    plan = edited(plan, rotate)
    S = 10 * 2
    ref = _per_sample_reference(plan, S, 2)
    knots = np.arange(0, len(ref["zmp"]) * 2, S) // 2  # the points among the controller samples
    assert ref["zmp"][knots].min() > 0.05  # every point's ZMP is well inside
    assert ref["zmp"].min() < -0.05  # in between it is far outside
    assert ref["margin"].min() > 0.02  # statically the CoM stays inside: only the ZMP check can see it
    v = gate.check(plan, offline=True)
    assert not v.passed and v.check == "zmp", v.summary()
    first = int(np.flatnonzero(ref["zmp"] < -1e-4)[0]) * 2  # controller sample -> gate sample
    assert v.sample_index == first and v.sample_index % S != 0
    assert v.point_index == first // S and "between points" in v.message
    assert v.stats["zmp"]["min_margin_m"] == pytest.approx(ref["zmp"].min(), abs=1e-9)


# --------------------------------------------------------------------------- property


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink])
@given(
    arm=st.floats(-1.2, 0.2),
    waist=st.floats(-0.15, 0.35),  # WP lower limit is -0.1745 rad
    mass=st.floats(0.0, 12.0),
    holding=st.sampled_from(["none", "right"]),
    threshold=st.floats(0.0, 0.12),
)
@example(arm=-1.2, waist=0.35, mass=12.0, holding="right", threshold=0.12)  # far below the margin
@example(arm=-0.1, waist=0.0, mass=0.0, holding="none", threshold=0.0)  # comfortably above
def test_any_plan_below_the_margin_is_vetoed(arm, waist, mass, holding, threshold):
    # the margin alone (effort and grip: test_gate_effort.py; the policy's floor: test_gate_policy.py)
    gate = SafetyGate(GateSettings(check_limits=False), policy=SafetyPolicy(margin_floor_m=0.0))
    plan = build_plan({"RSP": arm, "WP": waist}, duration_s=2.0, mass_kg=mass, holding=holding, threshold_m=threshold)
    true = true_min_margin(plan)
    v = gate.check(plan, offline=True)
    if true < threshold - 1e-4 - 1e-9:
        assert not v.passed and v.check == "com_margin", v.summary()
    elif true > threshold - 1e-4 + 1e-9 and v.check != "zmp":
        assert v.passed, v.summary()


def test_gate_cli(tmp_path, plan):
    from click.testing import CliRunner

    from service.cli.main import cli

    good = tmp_path / "good.json"
    good.write_text(json.dumps({**plan, "threshold_m": 0.03}))  # at the built-in policy's floor
    runner = CliRunner()
    out = runner.invoke(cli, ["gate", "check", str(good), "--json"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.stdout)["passed"] is True
    out = runner.invoke(cli, ["gate", "check", str(good), "--threshold-mm", "500"])
    assert out.exit_code == 1 and "com_margin" in out.stdout
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    out = runner.invoke(cli, ["gate", "check", str(bad)])
    assert out.exit_code == 2
    assert "not valid JSON" in (out.stderr if hasattr(out, "stderr") else out.output)


def test_canonical_bytes_fast_path(gate, plan):
    from schemas.plan import canonical_json

    raw = canonical_json(plan)
    names, q, _ = stance_state()
    ok = Approval(plan_sha256(plan), datetime.now(timezone.utc) + timedelta(minutes=5))
    v, parsed = gate.check_json(raw, approval=ok, measured=MeasuredState(names, q))
    assert v.passed and v.plan_sha256 == plan_sha256(plan)
    assert [p.q for p in parsed.trajectory] == [p["q"] for p in plan["trajectory"]]
    assert {"hash_s", "json_s"} <= set(v.stats["timing"])  # the hash and the JSON reading, each timed on its own
    # same plan, other bytes (not canonical): the hash check refuses it
    v, _ = gate.check_json(json.dumps(plan, indent=1).encode(), approval=ok, measured=MeasuredState(names, q))
    assert not v.passed and v.check == "plan_hash"
    v, parsed = gate.check_json(b'{"schema": NaN}', offline=True)
    assert not v.passed and v.check == "structure" and parsed is None
