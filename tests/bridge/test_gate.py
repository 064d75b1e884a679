"""The safety gate: an independent channel that agrees with the planner, and every check's veto."""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

from robot_bridge.gate import Approval, GateSettings, MeasuredState, SafetyGate
from schemas.plan import plan_sha256

from .conftest import REPO
from .plans import build_plan, edited, stance_state, true_min_margin


@pytest.fixture(scope="module")
def gate() -> SafetyGate:
    return SafetyGate()


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

    from planner.kinematics_batch import BatchKinematics
    from planner.robot_model import frame_poses, load_robot
    from robot_bridge.robot_files import robot_files
    from robot_bridge.urdf_kinematics import BatchFK, load_urdf

    robot = load_robot(robot_name)
    rng = np.random.default_rng(7)
    n = 200
    lo, hi = np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi)
    Q = rng.uniform(lo, hi, size=(n, robot.nq))
    base = np.hstack([rng.normal(scale=0.5, size=(n, 3)), rng.normal(size=(n, 4))])
    base[:, 3:] /= np.linalg.norm(base[:, 3:], axis=1, keepdims=True)
    frames = ["l_tcp", "r_tcp", "l_sole", "r_sole"]
    # Shuffled column order: the gate maps the plan's joint names, it does not assume an order.
    perm = rng.permutation(robot.nq)
    fk = BatchFK(load_urdf(str(robot_files(robot_name).urdf)), [robot.joint_names[i] for i in perm])
    com, poses = fk.com_and_frames(base, Q[:, perm], frames)
    ref_com, ref = BatchKinematics(robot).com_and_frames(base, Q, frames)
    assert np.abs(com - ref_com).max() < 1e-9
    for f in frames:
        assert np.abs(poses[f][0] - ref[f][0]).max() < 1e-9
        assert np.abs(poses[f][1] - ref[f][1]).max() < 1e-9
    data = robot.create_data()
    for k in range(0, n, 40):  # and pinocchio itself, state by state
        qp = robot.to_pin_q(base[k], Q[k])
        assert np.abs(pin.centerOfMass(robot.pin_model, data, qp) - com[k]).max() < 1e-9
        for f, M in zip(frames, frame_poses(robot, data, base[k], Q[k], frames)):
            assert np.abs(M.translation - poses[f][1][k]).max() < 1e-9
            assert np.abs(M.rotation - poses[f][0][k]).max() < 1e-9
    assert abs(fk.total_mass - robot.total_mass) < 1e-9


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
    p = build_plan({"RSP": -0.3}, duration_s=1.0)
    coarse = edited(p, lambda p: (p.__setitem__("trajectory", p["trajectory"][::2]), p.__setitem__("dt_s", 0.01),
                                  [pt.__setitem__("t", i * 0.01) for i, pt in enumerate(p["trajectory"])]))
    v = gate.check(coarse, offline=True)
    assert v.passed, v.summary()
    assert v.samples == (len(coarse["trajectory"]) - 1) * 4 + 1  # 2 controller periods per point, x2 midpoints


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
    gate = SafetyGate()
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
    good.write_text(json.dumps(plan))
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
    assert v.passed and parsed == plan and v.plan_sha256 == plan_sha256(plan)
    # same plan, other bytes (not canonical): the hash check refuses it
    v, _ = gate.check_json(json.dumps(plan, indent=1).encode(), approval=ok, measured=MeasuredState(names, q))
    assert not v.passed and v.check == "plan_hash"
    v, parsed = gate.check_json(b'{"schema": NaN}', offline=True)
    assert not v.passed and v.check == "structure" and parsed is None


def test_chord_bound_holds_on_random_segments():
    """The bound that lets the gate skip exact kinematics at provably safe in-between samples."""
    from robot_bridge.robot_files import robot_files
    from robot_bridge.urdf_kinematics import BatchFK, load_urdf

    model = load_urdf(str(robot_files("hrp5p").urdf))
    fk = BatchFK(model)
    rng = np.random.default_rng(3)
    n = 300
    qa = rng.uniform(np.maximum(model.lower, -2), np.minimum(model.upper, 2), size=(n, len(model.joint_names)))
    step = rng.normal(size=qa.shape) * rng.choice([0.002, 0.02, 0.2], size=(n, 1))
    qb = np.clip(qa + step, model.lower, model.upper)
    base = np.array([0.0, 0.0, 0.8, 0.0, 0.0, 0.0, 1.0])
    frames = ["l_sole", "r_tcp"]
    ca, fa = fk.com_and_frames(base, qa, frames)
    cb, fb = fk.com_and_frames(base, qb, frames)
    cm, fm = fk.com_and_frames(base, 0.5 * (qa + qb), frames)
    dq = np.abs(qb - qa) @ fk.column_weight
    bound = fk.curvature_bound * dq * dq / 8.0
    assert np.all(np.linalg.norm(cm - 0.5 * (ca + cb), axis=1) <= bound + 1e-12)
    for f in frames:
        assert np.all(np.linalg.norm(fm[f][1] - 0.5 * (fa[f][1] + fb[f][1]), axis=1) <= bound + 1e-12)
