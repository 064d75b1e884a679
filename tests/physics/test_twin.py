"""The physics twin (MuJoCo) on its own: at rest it carries the weight where the CoM is; a planned motion stands,
the same motion with a far heavier object does not; the same run gives the same report; bad input is refused."""

from __future__ import annotations

import json
import re
from functools import lru_cache

import numpy as np
import pytest
from click.testing import CliRunner

from robot_bridge.physics.model import build_twin_model
from robot_bridge.physics.settings import ContactSettings, StabilizerSettings, TwinSettings
from robot_bridge.physics.simulate import SAMPLE_COLUMNS, SimulateInputError, hold, simulate
from robot_bridge.physics.twin import G, Twin
from robot_bridge.robot_files import robot_files
from tests.bridge.plans import build_plan, stance_state


@lru_cache(maxsize=None)
def arm_plan(mass_kg: float = 8.0) -> str:
    """A short plan (1.5 s) that swings the right arm out holding an object: canonical JSON, so each test gets
    its own copy."""
    return json.dumps(build_plan({"RSP": -0.4, "REP": -0.3}, holding="right", mass_kg=mass_kg, duration_s=1.5))


def _plan() -> dict:
    return json.loads(arm_plan())


def _standing(robot: str, stance: str, settings: TwinSettings, load_kg: float, seconds: float) -> Twin:
    """A twin of ``robot`` standing still in ``stance`` for ``seconds``, with ``load_kg`` taken into the right hand
    8 cm along its approach axis (no load when 0); no fault on the way."""
    names, q, base = stance_state(robot, stance)  # loads the robot: a spec robot's derived URDF is written
    files = robot_files(robot)
    tm = build_twin_model(files.urdf, files.spec, names, settings)
    twin = Twin(tm, np.array(base), np.array(q), {"left": True, "right": True}, settings, object_mass_kg=load_kg)
    p, R = twin.tcp_pose("right")
    twin.grasp("right", p + R @ np.array([0.0, 0.0, 0.08]))
    for _ in range(int(round(seconds / 0.005))):
        assert twin.control(np.array(q), "right" if load_kg else "none", 0.005) is None
    return twin


@pytest.mark.parametrize("robot,stance,load_kg", [("hrp5p", "upright", 0.0), ("hrp5p", "upright", 6.0),
                                                  ("hrp5p", "crouched", 0.0), ("jvrc1", "upright", 0.0),
                                                  ("talos", "upright", 0.0), ("g1", "upright", 0.0)])
def test_the_twin_at_rest_carries_its_weight_under_its_com(robot, stance, load_kg):
    """Standing still (with an object in the right hand when ``load_kg`` > 0): the soles' normal forces add up to
    the robot's and the object's weight within 1 %, and the CoP is the CoM's ground projection within 2 mm. The
    spec robots (TALOS, G1) are built from the URDF the planner derives from their spec."""
    if robot == "talos":
        pytest.importorskip("cmeel", reason="TALOS needs the example-robot-data package (the `talos` extra)")
    twin = _standing(robot, stance, TwinSettings(), load_kg, seconds=2.0)  # the load ramp, then rest
    ms = twin.last
    weight = (twin.tm.total_mass_kg + load_kg) * G
    assert sum(ms.foot_forces_n.values()) == pytest.approx(weight, rel=0.01)
    assert np.linalg.norm(ms.cop - ms.com[:2]) < 0.002, (ms.cop, ms.com)
    assert twin.load_mass["right"] == pytest.approx(load_kg)
    if load_kg:  # the wrist sensors read the held object's weight
        assert ms.held_load_n == pytest.approx(load_kg * G, rel=0.01)


def test_the_sole_contacts_are_simulated_with_the_soles_settings_alone():
    """The contact the twin simulates is the soles' settings (time constant, impedance, friction), not a mix with the
    floor's MuJoCo defaults (equal priorities would average the two geoms' solref and solimp and take the larger
    friction): standing with 6 kg in the hand, every sole contact carries exactly the settings, and the soles sink
    less than 0.5 mm (the floor's defaults mixed in let them sink 2-4 mm)."""
    settings = TwinSettings(contact=ContactSettings(timeconst_s=0.004, friction=0.6))
    twin = _standing("hrp5p", "upright", settings, 6.0, seconds=1.0)
    contacts = [twin.d.contact[i] for i in range(twin.d.ncon)]
    assert len(contacts) >= 4
    for c in contacts:
        assert tuple(c.solref) == pytest.approx((0.004, 1.0))
        assert tuple(c.solimp[:2]) == pytest.approx(settings.contact.impedance)
        assert c.friction[0] == pytest.approx(0.6)
        assert -c.dist < 0.0005, c.dist


def test_at_rest_a_load_coming_on_dips_the_cop_a_little_and_the_twin_settles_where_the_plan_has_its_com():
    """``hold``: the twin standing still in the plan's last posture. When the hand takes the 8 kg object within the
    second before (the first half of the plan holds nothing), its weight coming on moves the CoP past where it
    settles, by 1-5 mm: the grasp puts the load at the object's CoM without a jolt (a history of the load's position
    that jumped at the grasp asked the CoP to the polygon's edge). Held all along, the load came on during the
    settle, and the window shows no dip (0.1 mm). Either way it settles to the same CoP margin (0.5 mm), the plan's
    static margin there (1 mm): the twin's CoM is the plan's, the object's weight at the object's CoM, not at the
    TCP. A sample outside the plan and a settle that is not a number are refused."""
    plan = _plan()
    last = len(plan["trajectory"]) - 1
    held = hold(plan, last)
    changed = _plan()
    for point in changed["trajectory"][: last // 2]:
        point["holding"] = "none"
    taken = hold(changed, last)
    assert held.holding == taken.holding == "right" and held.fault is None and taken.fault is None
    assert taken.settled_cop_margin_m - 0.005 < taken.min_cop_margin_m < taken.settled_cop_margin_m - 0.001
    assert held.min_cop_margin_m > held.settled_cop_margin_m - 0.0001
    assert taken.settled_cop_margin_m == pytest.approx(held.settled_cop_margin_m, abs=0.0005)
    assert held.settled_cop_margin_m == pytest.approx(held.plan_margin_m, abs=0.001)
    with pytest.raises(SimulateInputError, match="sample"):
        hold(plan, last + 1)
    with pytest.raises(SimulateInputError, match="settle_s"):
        hold(plan, last, settle_s=float("nan"))


def test_the_planned_object_stands_and_a_six_times_heavier_one_does_not():
    plan = _plan()
    stood = simulate(plan)
    assert stood.stood and not stood.report["fell"], stood.report["fault"]
    assert stood.report["min_cop_margin_m"] > 0.01
    assert 0 < stood.report["cop_margin_ratio"] <= 2.0
    heavy = simulate(plan, TwinSettings(mass_scale=6.0))
    assert not heavy.stood
    assert heavy.report["fault"]["kind"] in ("fall", "foot_tilt", "foot_lift", "torque_saturation")
    assert heavy.report["mass_scale"] == 6.0


#: The drill tasks' object (drill-upright, drill-handover): the lightest built-in load, whose six-fold weight the arm
#: and the stabilizer carry without a fall or a saturated joint.
DRILL_KG = 1.3


@pytest.mark.parametrize("scale,stands", [(1.0, True), (1.4, True), (6.0, False)])
def test_the_payload_check_faults_a_load_far_from_the_planned_one(scale, stands):
    """The controller's payload check: the wrists' sensors read the held load; within 50 % + 5 N of the planned
    weight (1.4 x the drill) the plan stands, six times the drill faults (payload_mismatch) shortly after the
    weight is on the hand (the load ramp, the settle time and the debounce: 0.45 s)."""
    plan = json.loads(arm_plan(DRILL_KG))
    res = simulate(plan, TwinSettings(mass_scale=scale))
    assert res.stood is stands, res.report["fault"]
    if not stands:
        fault = res.report["fault"]
        assert fault["kind"] == "torque_saturation" and fault["detail"].startswith("payload_mismatch:"), fault
        read = float(re.search(r"read ([0-9.]+) N of held load", fault["detail"]).group(1))
        assert read == pytest.approx(DRILL_KG * scale * G, rel=0.1)  # the sensors read the real, heavier load
        # the hand holds from the first sample: the check judges from the settle's start (-1 s) on
        assert fault["at_s"] == pytest.approx(-1.0 + 0.25 + 0.1 + 0.1, abs=0.011)


def test_simulate_cli_with_a_six_times_heavier_drill_exits_faulted(tmp_path):
    """`regrasp simulate --mass-scale 6` on a plan carrying the drill's mass: exit 1, the payload fault in the report;
    the planned mass: exit 0."""
    from service.cli.simulate import simulate as cli

    plan_file = tmp_path / "drill.json"
    plan_file.write_text(arm_plan(DRILL_KG))
    runner = CliRunner()
    heavy = runner.invoke(cli, [str(plan_file), "--mass-scale", "6", "--out", str(tmp_path / "heavy")])
    assert heavy.exit_code == 1, heavy.output
    report = json.loads((tmp_path / "heavy" / "simreport.json").read_text())
    assert report["mass_scale"] == 6.0 and report["fault"]["detail"].startswith("payload_mismatch:"), report["fault"]
    planned = runner.invoke(cli, [str(plan_file), "--out", str(tmp_path / "planned")])
    assert planned.exit_code == 0, planned.output


def test_the_same_run_twice_gives_the_same_report_and_samples():
    plan = _plan()
    a, b = simulate(plan), simulate(plan)
    ra, rb = dict(a.report), dict(b.report)
    assert ra.pop("wall_s") >= 0 and rb.pop("wall_s") >= 0
    assert ra == rb
    assert a.samples == b.samples
    assert len(a.samples) == len(plan["trajectory"])  # one row per plan sample at speed 1
    assert len(a.samples[0]) == len(SAMPLE_COLUMNS)


def test_the_stabilizer_is_a_real_switch():
    """Off, the same plan gives another CoP history (the stabilizer acts), and the report says which ran."""
    plan = _plan()
    on = simulate(plan)
    off = simulate(plan, TwinSettings(stabilizer=StabilizerSettings(enabled=False)))
    assert on.report["stabilizer"] is True and off.report["stabilizer"] is False
    assert on.samples != off.samples


def test_simulate_cli_writes_the_report_and_exits_by_the_outcome(tmp_path):
    from service.cli.simulate import simulate as cli

    plan_file = tmp_path / "plan.json"
    plan_file.write_text(arm_plan())
    runner = CliRunner()
    ok = runner.invoke(cli, [str(plan_file), "--out", str(tmp_path / "ok"), "--json"])
    assert ok.exit_code == 0, ok.output
    report = json.loads((tmp_path / "ok" / "simreport.json").read_text())
    assert report["schema"] == "regrasp.simreport/1" and report["fault"] is None
    assert set(report) >= {"plan_sha256", "robot", "engine", "stabilizer", "speed", "mass_scale", "fell", "fell_at_s",
                           "fault", "min_cop_margin_m", "min_cop_margin_at_s", "cop_margin_ratio",
                           "max_tracking_error_rad", "max_torque_ratio", "foot_slip_m", "foot_tilt_rad", "wall_s"}
    assert report["engine"] == {"name": "mujoco", "version": report["engine"]["version"], "timestep_s": 0.001}
    header = (tmp_path / "ok" / "samples.csv").read_text().splitlines()[0]
    assert header == ",".join(SAMPLE_COLUMNS)
    heavy = runner.invoke(cli, [str(plan_file), "--out", str(tmp_path / "heavy"), "--mass-scale", "6"])
    assert heavy.exit_code == 1, heavy.output


@pytest.mark.parametrize("edit,words", [
    (lambda p: p.update(status="infeasible"), "not solved"),
    (lambda p: p["trajectory"][3]["q"].__setitem__(0, float("nan")), "non-finite"),
    (lambda p: p["robot"].update(name="nao"), "unknown robot"),
    (lambda p: p.update(dt_s=0.0025), "multiple of the 1 ms"),
    (lambda p: p["trajectory"][2].update(holding="teeth"), "holding"),
])
def test_a_plan_the_twin_cannot_play_is_refused_in_one_line(edit, words, tmp_path):
    plan = _plan()
    edit(plan)
    with pytest.raises(SimulateInputError, match=words):
        simulate(plan)
    from service.cli.simulate import simulate as cli

    f = tmp_path / "bad.json"
    f.write_text(json.dumps(plan).replace("NaN", "NaN"))
    res = CliRunner().invoke(cli, [str(f), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "Traceback" not in res.output
