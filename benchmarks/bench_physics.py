"""The physics twin: every built-in scenario's plan in MuJoCo, the sensitivity of the result to each modelling
choice, the cost, and JVRC-1 against the lab's published gains.

Sections (``--section``, default all):

- ``rest``: each robot standing still in its upright stance for 2 s: the soles' normal forces over its weight, and
  the distance from the CoP to the CoM's ground projection.
- ``scenarios``: each built-in scenario planned with seed 1, played with the stabilizer at 1x, without it at 1x,
  with it at 2x (informative) and with the object 6x heavier: stood or the fault, the smallest CoP margin and
  ``cop_margin_ratio`` (CoP margin over the plan's CoM margin), and the real-time factor of each run.
- ``speed``: ``regrasp simulate``'s speed alone: each scenario's plan at 1x with the stabilizer, three runs, the
  real-time factor (plan duration plus the 2 s of settling, over the wall time) of the fastest and the slowest, with
  the machine's load average before and after (the figure depends on what else the 2 cores run).
- ``payload``: what the wrist sensors read of the planned object at 1x and 2x (the held load over the planned
  weight, smallest and largest, while the payload check judged it): how much of the check's 50 % + 5 N tolerance the
  motion itself takes.
- ``hold``: each scenario's plan at 1x with the stabilizer, then the twin standing still in the posture where that
  run's smallest CoP margin came, the hands' holding changing as the plan's did over the second before (a grasp's
  load coming on, a release's going), then 3 s more: the smallest and the settled CoP margin at rest, over the
  plan's smallest CoM margin, against the run's; and the run with a stiffer stabilizer (``STIFF_COP``: CoP gain
  16 /s, the moments at the ankles only), to show how much the figure owes to the stand-in controller. What the feet feel with no
  motion at all is the part of the run's figure that no timing can take away.
- ``sweep``: the upright plan with one setting changed at a time (contact softness, servo stiffness and damping,
  rotor inertia, load ramp, gravity feed-forward, stabilizer gains): how far each moves the smallest CoP margin.
- ``jvrc1``: JVRC-1 swinging its right arm out holding 2 kg (3 s), with our derived gains and with gains of the size the HRP-5P
  lab publishes for its MuJoCo JVRC-1 (legs kp 5000-6000 / kd 20-50, waist 5000 / 32, neck 1000 / 21, arms
  1100-1200 / 70-80, wrists 500 / 24: the middle of each range, typed from those figures, not from its files).

Plans are made once (``regrasp plan --seed 1``) into ``--plans DIR`` and reused. Figures depend on the machine's
load for the wall-clock columns only. Run: ``python benchmarks/bench_physics.py [--section S] [--plans DIR]``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from robot_bridge.physics.settings import (  # noqa: E402
    ContactSettings,
    ServoDefaults,
    StabilizerSettings,
    TwinSettings,
)
from robot_bridge.physics.simulate import hold, simulate  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SCENARIOS = ("upright", "staggered", "crouched", "one-legged", "drill-upright", "drill-handover", "talos-upright",
             "g1-upright")
#: Hand configurations given to the planner instead of ``hands: auto`` (which surveys all four first): TALOS's
#: survey (``regrasp survey --scenario talos-upright``, as ``regrasp demo --robot talos`` runs it) keeps left-left among
#: its recommended configurations, the first that plans; the survey alone outlasts a benchmark's patience on a busy
#: 2-core machine (over 15 min).
PLAN_HANDS = {"talos-upright": "left-left"}
#: Typed from the published figures (anchors): the middle of each range, per joint group.
LAB_GAINS_JVRC1 = {"legs": (5500.0, 35.0), "waist": (5000.0, 32.0), "neck": (1000.0, 21.0), "arms": (1150.0, 75.0),
                   "wrists": (500.0, 24.0)}


def planner_digest() -> str:
    """What decides a plan: the planner's and the schemas' code and the robots' files. Plans are cached under it, so
    a changed planner plans again instead of measuring a stale plan."""
    h = hashlib.sha256()
    for folder, pattern in (("planner", "*.py"), ("schemas", "*.py"), ("robot_data", "*.yaml"),
                            ("robot_data", "*.urdf")):
        for f in sorted((REPO / folder).rglob(pattern)):
            h.update(str(f.relative_to(REPO)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:12]


def plan_file(plans: Path, scenario: str, robot: str | None = None) -> Path:
    """The scenario's seed-1 plan, planned once into ``plans`` (the benchmark's cache) and reused."""
    out = plans / f"{scenario}{'-' + robot if robot else ''}.json"
    if not out.is_file():
        cmd = [sys.executable, "-m", "service.cli.main", "plan", "--scenario", scenario, "--seed", "1", "--quiet",
               "--out", str(out)]
        if robot:
            cmd += ["--robot", robot]
        if scenario in PLAN_HANDS and not robot:
            cmd += ["--hands", PLAN_HANDS[scenario]]
        t = time.perf_counter()
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
        print(f"  planned {out.name} in {time.perf_counter() - t:.0f} s (exit {proc.returncode})", file=sys.stderr)
    return out


def run(plan: dict, settings: TwinSettings, speed: float = 1.0) -> dict:
    cpu = time.process_time()
    rep = simulate(plan, settings, speed=speed).report
    cpu = time.process_time() - cpu
    duration = plan["trajectory"][-1]["t"] / speed + 2 * settings.settle_s
    rep["realtime_factor"] = duration / rep["wall_s"]
    rep["cpu_realtime_factor"] = duration / cpu  # the same on a core of its own, whatever else the machine runs
    return rep


def cell(rep: dict) -> str:
    m = rep["min_cop_margin_m"]
    ratio = rep["cop_margin_ratio"]
    fault = rep["fault"]
    payload = " (payload_mismatch)" if fault is not None and fault["detail"].startswith("payload_mismatch") else ""
    head = "stood" if fault is None else f"**{fault['kind']}**{payload} at {fault['at_s']:.1f} s"
    tail = "" if m is None else f", {m * 1000:.1f} mm ({ratio:.2f})"
    return head + tail


def rest() -> None:
    import numpy as np

    from robot_bridge.physics.model import build_twin_model
    from robot_bridge.physics.twin import G, Twin
    from robot_bridge.robot_files import robot_files
    from tests.bridge.plans import stance_state

    print("\n## At rest (upright stance, 2 s)\n")
    print("| robot | mass | normal force / weight | CoP to CoM projection | max tracking error |")
    print("|---|---|---|---|---|")
    for robot in ("hrp5p", "jvrc1", "talos", "g1"):
        try:
            names, q, base = stance_state(robot, "upright")
            files = robot_files(robot)
        except Exception as exc:  # noqa: BLE001 - a robot whose files are not installed is listed as such
            print(f"| {robot} | not available ({type(exc).__name__}) | | | |")
            continue
        settings = TwinSettings()
        twin = Twin(build_twin_model(files.urdf, files.spec, names, settings), np.array(base), np.array(q),
                    {"left": True, "right": True}, settings)
        for _ in range(400):
            twin.control(np.array(q), "none", 0.005)
        ms = twin.last
        ratio = sum(ms.foot_forces_n.values()) / (twin.tm.total_mass_kg * G)
        print(f"| {robot} | {twin.tm.total_mass_kg:.1f} kg | {ratio:.6f} | "
              f"{np.linalg.norm(ms.cop - ms.com[:2]) * 1000:.3f} mm | {ms.tracking_error_rad:.1e} rad |")


def scenarios(plans: Path, names: tuple[str, ...] = SCENARIOS) -> None:
    print(f"\n## Built-in scenarios (seed 1): min CoP margin (cop_margin_ratio); {load_average()}\n")
    print("| scenario | plan min CoM margin | stabilizer 1x | no stabilizer 1x | stabilizer 2x | object x6 | "
          "real time x (1x run) |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        path = plan_file(plans, name)
        if not path.is_file():
            print(f"| {name} | not planned | | | | | |")
            continue
        plan = json.loads(path.read_text())
        if plan.get("status") != "solved":
            print(f"| {name} | {plan.get('status')} | | | | | |")
            continue
        on = run(plan, TwinSettings())
        off = run(plan, TwinSettings(stabilizer=StabilizerSettings(enabled=False)))
        fast = run(plan, TwinSettings(), speed=2.0)
        heavy = run(plan, TwinSettings(mass_scale=6.0))
        print(f"| {name} | {plan['min_margin_m'] * 1000:.1f} mm | {cell(on)} | {cell(off)} | {cell(fast)} | "
              f"{cell(heavy)} | {on['realtime_factor']:.1f} |", flush=True)
    print(f"\n{load_average()}")


#: A stiffer stand-in balance controller than the default: the CoP loop's integral gain 16 /s (default 4), all of the
#: corrective moment at the ankles (default 30 % at the hips).
STIFF_COP = StabilizerSettings(cop_gain=16.0, hip_share=0.0)


def at_rest(plans: Path, names: tuple[str, ...] = SCENARIOS) -> None:
    print("\n## The run's smallest CoP margin against the twin at rest in that posture (stabilizer on; over the plan's "
          "smallest CoM margin)\n")
    print("| scenario | plan min CoM margin | run at 1x: min CoP margin, at | at rest there (holding at the end): smallest | "
          "at rest: settled after 3 s | run at 1x, CoP gain 16 /s at the ankles |")
    print("|---|---|---|---|---|---|")
    for name, plan in solved_plans(plans, names):
        rep = run(plan, TwinSettings())
        plan_min = float(plan["min_margin_m"])
        if rep["min_cop_margin_at_s"] is None:
            print(f"| {name} | {plan_min * 1000:.1f} mm | {cell(rep)} | | | |")
            continue
        index = min(int(round(rep["min_cop_margin_at_s"] / float(plan["dt_s"]))), len(plan["trajectory"]) - 1)
        still = hold(plan, index)
        stiff = run(plan, TwinSettings(stabilizer=STIFF_COP))
        fault = "" if still.fault is None else f", **{still.fault.kind}**"
        print(f"| {name} | {plan_min * 1000:.1f} mm | {rep['min_cop_margin_m'] * 1000:.1f} mm "
              f"({rep['cop_margin_ratio']:.2f}) at {rep['min_cop_margin_at_s']:.2f} s | "
              f"{still.min_cop_margin_m * 1000:.1f} mm ({still.min_cop_margin_m / plan_min:.2f}), {still.holding}"
              f"{fault} | {still.settled_cop_margin_m * 1000:.1f} mm ({still.settled_cop_margin_m / plan_min:.2f}) | "
              f"{cell(stiff)} |",
              flush=True)


def solved_plans(plans: Path, names: tuple[str, ...]):
    """Each scenario's seed-1 plan (planned once), those that solved."""
    for name in names:
        path = plan_file(plans, name)
        if path.is_file() and (plan := json.loads(path.read_text())).get("status") == "solved":
            yield name, plan


def load_average() -> str:
    return "load average " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


def speed(plans: Path, names: tuple[str, ...] = SCENARIOS, runs: int = 3) -> None:
    print(f"\n## regrasp simulate speed (1 ms physics, control at 200 Hz, stabilizer on, 1x); {load_average()}\n")
    print("| scenario | simulated s | wall s (fastest-slowest) | real time x (fastest-slowest) | on its own core: CPU time x |")
    print("|---|---|---|---|---|")
    factors, cpus = [], []
    for name, plan in solved_plans(plans, names):
        reps = [run(plan, TwinSettings()) for _ in range(runs)]
        walls = sorted(r["wall_s"] for r in reps)
        x = sorted(r["realtime_factor"] for r in reps)
        factors += x
        cpu = sorted(r["cpu_realtime_factor"] for r in reps)
        cpus += cpu
        dur = plan["trajectory"][-1]["t"] + 2 * TwinSettings().settle_s
        print(f"| {name} | {dur:.1f} | {walls[0]:.2f}-{walls[-1]:.2f} | {x[-1]:.1f}-{x[0]:.1f} | "
              f"{cpu[-1]:.1f}-{cpu[0]:.1f} |", flush=True)
    if factors:
        print(f"\nslowest run {min(factors):.1f}x, fastest {max(factors):.1f}x real time ({len(factors)} runs); "
              f"CPU time {min(cpus):.1f}-{max(cpus):.1f}x; {load_average()}")


def payload(plans: Path, names: tuple[str, ...] = SCENARIOS) -> None:
    print("\n## What the wrist sensors read of the planned object (held load / planned weight, smallest-largest)\n")
    print("| scenario | object | 1x | 2x |")
    print("|---|---|---|---|")
    for name, plan in solved_plans(plans, names):
        cells = []
        for sp in (1.0, 2.0):
            res = simulate(plan, TwinSettings(), speed=sp)
            r = res.held_load_ratio
            tail = "" if res.report["fault"] is None else f" (until {res.report['fault']['kind']} at {res.report['fault']['at_s']:.1f} s)"
            cells.append("n/a" if r is None else f"{r[0]:.2f}-{r[1]:.2f}{tail}")
        print(f"| {name} | {plan['object']['mass_kg']:g} kg | {cells[0]} | {cells[1]} |", flush=True)


def sweep(plans: Path) -> None:
    plan = json.loads(plan_file(plans, "upright").read_text())
    base = run(plan, TwinSettings())
    print(f"\n## Sensitivity on upright (seed 1); default: {cell(base)}\n")
    print("| setting | value | result | change of min CoP margin |")
    print("|---|---|---|---|")
    variants = [
        ("contact time constant", "2 ms", TwinSettings(contact=ContactSettings(timeconst_s=0.002))),
        ("contact time constant", "20 ms", TwinSettings(contact=ContactSettings(timeconst_s=0.02))),
        ("contact impedance", "MuJoCo default (0.9, 0.95)", TwinSettings(contact=ContactSettings(impedance=(0.9, 0.95)))),
        ("servo stiffness (deflection at full effort)", "0.025 rad", TwinSettings(servo=ServoDefaults(stiffness_angle_rad=0.025))),
        ("servo stiffness (deflection at full effort)", "0.1 rad", TwinSettings(servo=ServoDefaults(stiffness_angle_rad=0.1))),
        ("servo damping ratio", "0.5", TwinSettings(servo=ServoDefaults(damping_ratio=0.5))),
        ("servo damping ratio", "2", TwinSettings(servo=ServoDefaults(damping_ratio=2.0))),
        ("rotor inertia per N*m", "0", TwinSettings(servo=ServoDefaults(armature_per_effort=0.0))),
        ("rotor inertia per N*m", "3e-3", TwinSettings(servo=ServoDefaults(armature_per_effort=3e-3))),
        ("gravity feed-forward", "off", TwinSettings(servo=ServoDefaults(gravity_feedforward=False))),
        ("load ramp", "0 (all at once)", TwinSettings(load_ramp_s=0.0)),
        ("load ramp", "1 s", TwinSettings(load_ramp_s=1.0)),
        ("stabilizer", "off", TwinSettings(stabilizer=StabilizerSettings(enabled=False))),
        ("stabilizer DCM gain", "0", TwinSettings(stabilizer=StabilizerSettings(dcm_gain=0.0))),
        ("stabilizer DCM gain", "4", TwinSettings(stabilizer=StabilizerSettings(dcm_gain=4.0))),
        ("stabilizer CoP gain", "0", TwinSettings(stabilizer=StabilizerSettings(cop_gain=0.0))),
        ("stabilizer CoP gain", "8", TwinSettings(stabilizer=StabilizerSettings(cop_gain=8.0))),
        ("stabilizer hip share", "0 (ankles only)", TwinSettings(stabilizer=StabilizerSettings(hip_share=0.0))),
        ("stabilizer hip share", "0.6", TwinSettings(stabilizer=StabilizerSettings(hip_share=0.6))),
    ]
    for name, value, settings in variants:
        rep = run(plan, settings)
        m, b = rep["min_cop_margin_m"], base["min_cop_margin_m"]
        delta = "n/a" if m is None or b is None else f"{(m - b) * 1000:+.1f} mm"
        print(f"| {name} | {value} | {cell(rep)} | {delta} |", flush=True)


def _group(joint: str) -> str:
    j = joint.upper()
    if "WRIST" in j:
        return "wrists"
    if any(k in j for k in ("SHOULDER", "ELBOW")):
        return "arms"
    if "NECK" in j:
        return "neck"
    if "WAIST" in j:
        return "waist"
    return "legs"


def jvrc1(plans: Path) -> None:
    from robot_bridge.physics import model as twin_model
    from robot_bridge.robot_files import robot_files

    from tests.bridge.plans import build_plan

    # The built-in upright task fitted to JVRC-1 has no plan at seed 1 (infeasible): a 3 s swing of the right arm
    # holding 2 kg out and back (rest to rest), made with the planner's kinematics, stands in for it.
    plan = build_plan({"R_SHOULDER_P": -0.6, "R_ELBOW_P": -0.5}, robot_name="jvrc1", holding="right", mass_kg=2.0,
                      duration_s=3.0, threshold_m=0.02)
    derived = run(plan, TwinSettings())
    files = robot_files("jvrc1")
    names = [n for n in plan["robot"]["joint_names"] if not n.endswith("_JAW")]
    kp = {n: LAB_GAINS_JVRC1[_group(n)][0] for n in names}
    kd = {n: LAB_GAINS_JVRC1[_group(n)][1] for n in names}
    lab_spec = {**files.spec, "sim": {"kp": kp, "kd": kd}}
    original = twin_model.build_twin_model

    def with_lab_gains(urdf, spec, joint_names, settings):
        return original(urdf, lab_spec, joint_names, settings)

    twin_model.build_twin_model = with_lab_gains
    import robot_bridge.physics.simulate as sim_module

    sim_module.build_twin_model = with_lab_gains
    try:
        lab = run(plan, TwinSettings())
        lab_off = run(plan, TwinSettings(stabilizer=StabilizerSettings(enabled=False)))
    finally:
        sim_module.build_twin_model = original
        twin_model.build_twin_model = original
    tm = original(files.urdf, files.spec, plan["robot"]["joint_names"], TwinSettings())
    ours = {s.name: (s.kp, s.kd) for s in tm.servos}
    print("\n## JVRC-1: derived gains against the lab's published sizes (right arm out with 2 kg, 3 s)\n")
    print("| joint group | lab kp / kd (published sizes) | ours kp / kd (derived, range) |")
    print("|---|---|---|")
    for group, (lkp, lkd) in LAB_GAINS_JVRC1.items():
        mine = [ours[n] for n in names if _group(n) == group]
        if mine:
            print(f"| {group} | {lkp:.0f} / {lkd:.0f} | {min(k for k, _ in mine):.0f}-{max(k for k, _ in mine):.0f} / "
                  f"{min(d for _, d in mine):.0f}-{max(d for _, d in mine):.0f} |")
    print("\n| gains | result | max tracking error | max torque ratio |")
    print("|---|---|---|---|")
    for label, rep in (("derived, stabilizer", derived), ("lab sizes, stabilizer", lab), ("lab sizes, no stabilizer", lab_off)):
        print(f"| {label} | {cell(rep)} | {rep['max_tracking_error_rad']:.4f} rad | {rep['max_torque_ratio']:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--section", choices=("all", "rest", "scenarios", "hold", "speed", "payload", "sweep", "jvrc1"),
                    default="all")
    ap.add_argument("--scenarios", default=",".join(SCENARIOS), help="comma-separated built-in scenarios")
    ap.add_argument("--plans", type=Path, default=Path("~/.cache/hrp-regrasp/bench-physics").expanduser(),
                    help="folder of the seed-1 plans (made once per planner version, in a subfolder named by its digest)")
    args = ap.parse_args()
    names = tuple(n for n in args.scenarios.split(",") if n)
    args.plans = args.plans / f"planner-{planner_digest()}"
    args.plans.mkdir(parents=True, exist_ok=True)
    print(f"plans: {args.plans}")
    import mujoco

    print(f"MuJoCo {mujoco.__version__}, 1 ms physics, control at the plan's dt_s")
    if args.section in ("all", "rest"):
        rest()
    if args.section in ("all", "scenarios"):
        scenarios(args.plans, names)
    if args.section in ("all", "hold"):
        at_rest(args.plans, names)
    if args.section in ("all", "speed"):
        speed(args.plans, names)
    if args.section in ("all", "payload"):
        payload(args.plans, names)
    if args.section in ("all", "sweep"):
        sweep(args.plans)
    if args.section in ("all", "jvrc1"):
        jvrc1(args.plans)


if __name__ == "__main__":
    main()
