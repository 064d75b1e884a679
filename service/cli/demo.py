"""``regrasp demo``: the main job end to end on the embedded defaults.

1. Loads the robot, solves the four built-in stances, prints for each the CoM,
   the support polygon and the margin, and writes one picture per stance.
2. Runs the paper's scenario through the real service on loopback: the stability
   survey, the plan with the recommended hands, the two-person approval, the
   safety gate, the dispatch to the simulated controller, and the audit file.
   With ``--robot ROBOT`` the scenario is ROBOT's own version of the upright task
   (the built-in ``ROBOT-upright``, such as ``talos-upright``) where there is one,
   else the upright task with ROBOT swapped in; the controller simulator plays ROBOT.
"""

from __future__ import annotations

import time
from pathlib import Path

import click
from rich.table import Table

from .common import console, fail


def stance_step(out: Path, robot_name: str, fmt: str = "png") -> list[dict]:
    """Solve the built-in stances and draw them; returns one summary row per stance."""
    from planner.api.catalogue import BUILTIN_STANCES, StanceError, sole_size, solve_stance
    from planner.api.robots import load_robot
    from experiments.plots import plot_stance

    robot = load_robot(robot_name)
    rows = []
    for name in BUILTIN_STANCES:
        try:
            st = solve_stance(robot, name)
        except StanceError as exc:
            rows.append({"stance": name, "error": str(exc)})
            continue
        feet = [f.model_dump() for f in st.feet]
        sizes = {f["frame"]: sole_size(robot, f["frame"]) for f in feet}
        picture = plot_stance(out / f"stance-{name}.{fmt}", name=name, feet=feet, sole_sizes=sizes,
                              polygon=st.polygon.vertices, com=st.robot_com, margin_m=st.margin)
        rows.append({"stance": name, "com": st.robot_com, "polygon": st.polygon.vertices,
                     "margin_m": st.margin, "picture": picture})
    return rows


@click.command()
@click.option("--out", "out_dir", default="demo-out", show_default=True, type=click.Path(file_okay=False),
              help="Directory for the demo's artefacts.")
@click.option("--robot", "robot_name", default=None,
              help="The robot (a registered name, `regrasp robot list`): its stances, and the scenario runs with it "
                   "[default: the scenario's robot, hrp5p for upright].")
@click.option("--stances-only", is_flag=True, help="Only the first step: solve and draw the stances.")
@click.option("--scenario", default=None,
              help="The scenario the demo plans and executes [default: upright; with --robot ROBOT the built-in "
                   "ROBOT-upright where there is one, such as talos-upright].")
@click.option("--survey-states", default=0, show_default=True, type=click.IntRange(0, 1_000_000),
              help="0: the demo surveys with the scenario's own estimator (seeds until every interval is within "
                   "+-0.02), so it recommends what `regrasp survey` and `hands: auto` do; N: N states per seed over "
                   "10 seeds instead (a quicker look, whose recommendation may differ).")
@click.option("--speed", default=1.0, show_default=True, type=click.FloatRange(min=0.1),
              help="The simulated controller plays K times faster than real time (physics: simulated time).")
@click.option("--plant", type=click.Choice(["physics", "kinematic"]), default="physics", show_default=True,
              help="The simulated controller's plant: the MuJoCo twin, or a replay of the commands.")
@click.option("--format", "fmt", type=click.Choice(["png", "svg", "pdf"]), default="png", show_default=True,
              help="Format of the figures.")
def demo(out_dir: str, robot_name: str | None, stances_only: bool, scenario: str | None, survey_states: int | None,
         speed: float, plant: str, fmt: str) -> None:
    """Run the main job end to end on the embedded defaults and show its result."""
    from planner.api.catalogue import load_scenario
    from planner.errors import InputError
    from service.demo import default_scenario

    try:
        if scenario is None:
            scenario = default_scenario(robot_name) if robot_name else "upright"
        loaded = load_scenario(scenario)
        scenario_robot = loaded.robot
    except InputError as exc:
        fail(str(exc))
    robot_name = robot_name or scenario_robot
    # The scenario runs with the demo's robot: an override where the scenario names another one.
    robot_override = robot_name if robot_name != scenario_robot else None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    console.rule(f"[bold]regrasp demo[/] -> {out.resolve()}")
    console.print("[bold]1. Robot and stances[/]")
    rows = stance_step(out, robot_name, fmt)
    table = Table("stance", "CoM x, y, z (m)", "support polygon (x, y) m", "margin (mm)")
    for r in rows:
        if "error" in r:
            table.add_row(r["stance"], "-", r["error"], "-")
            continue
        poly = " ".join(f"({x:.3f},{y:.3f})" for x, y in r["polygon"])
        table.add_row(r["stance"], ", ".join(f"{v:.3f}" for v in r["com"]), poly, f"{r['margin_m'] * 1000:.1f}")
    console.print(table)
    for r in rows:
        if "picture" in r:
            console.print(f"  picture: {r['picture']}")
    task_stance = loaded.stance if isinstance(loaded.stance, str) else loaded.stance.name
    unsolved = [r["stance"] for r in rows if "error" in r]
    if task_stance in unsolved:
        fail(f"the task's stance {task_stance} could not be solved for {robot_name}", code=1)
    if unsolved:
        console.print(f"  {', '.join(unsolved)}: beyond {robot_name} (above); the task stands {task_stance}",
                      highlight=False)
    if stances_only:
        console.print(f"[green]done[/]: artefacts in {out.resolve()}")
        return
    from planner.api.robots import warm_up
    from service.demo import DemoSettings, run_demo

    console.print("  compiling the planner's kernels (a machine's first run; later runs load them from cache) ...")
    console.print(f"  planner kernels ready in {warm_up(robot_name):.1f} s")

    settings = DemoSettings(scenario=scenario, robot=robot_override, survey_states=survey_states or None,
                            controller_speed=speed, plant=plant, figure_format=fmt)
    console.print(f"[bold]2. Scenario {scenario} with {robot_name}"
                  + (f" (over the scenario's {scenario_robot})" if robot_override else "")
                  + " through the service, the gate and the simulated robot[/]")
    t0 = time.perf_counter()
    try:
        res = run_demo(out, settings, say=lambda m: console.print(f"  [dim]{time.perf_counter() - t0:6.1f} s[/] {m}"))
    except (RuntimeError, TimeoutError) as exc:
        fail(f"the demo failed: {exc} (logs: {out.resolve()}/service.log, controller-sim.log)", code=1)
    s = res.summary
    table = Table("", "")
    table.add_row("scenario", scenario)
    table.add_row("robot", s["robot"])
    table.add_row("R per configuration", ", ".join(f"{h} {r:.3f}" if r is not None else f"{h} n/a" for h, r in s["survey"].items()))
    table.add_row("recommended hands", str(s["recommended"]))
    table.add_row("planned hands", str(s["hands"]))
    table.add_row("min margin / threshold", f"{s['min_margin_m'] * 1000:.1f} mm / {s['threshold_m'] * 1000:.0f} mm")
    table.add_row("max effort ratio", f"{s['max_effort_ratio']:.2f} (static torque / limit, the worst joint)")
    table.add_row("planning time", f"{s['planning_time_s']:.1f} s")
    table.add_row("motion duration", f"{s['duration_s']:.1f} s (played at {speed:g}x by the simulated controller, "
                                     f"{plant} plant)")
    if s.get("physics"):
        table.add_row("physics dry run", s["physics"])
    table.add_row("execution", s["execution"])
    table.add_row("audit", s["audit"])
    table.add_row("demo time", f"{time.perf_counter() - t0:.1f} s")
    console.print(table)
    for name, path in res.artefacts.items():
        console.print(f"  {name}: {path}", highlight=False, soft_wrap=True)  # whole paths, to copy
    console.print("Open the MCAP file in Foxglove (File > Open) to replay the plan and the executed motion.")
    console.print("Operator console: run [bold]regrasp serve --dev[/] and open http://127.0.0.1:8000/ with a printed token.")
    if not res.ok:
        fail(f"execution ended {s['execution']}" if s.get("execution") != "succeeded" else f"the audit file is {s['audit']}",
             code=1)
    console.print(f"[green]done[/]: artefacts in {out.resolve()}")
