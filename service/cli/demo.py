"""``regrasp demo``: the main job end to end on the embedded defaults.

It grows with each capability. Today it loads the robot, solves the four
built-in stances, prints for each the CoM, the support polygon and the margin,
and writes one picture per stance.
"""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from .common import console, fail


def stance_step(out: Path, robot_name: str) -> list[dict]:
    """Solve the built-in stances and draw them; returns one summary row per stance."""
    from planner.robot_model import load_robot
    from planner.stances import BUILTIN_STANCES, StanceError, sole_size, solve_stance
    from service.plots import plot_stance

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
        picture = plot_stance(out / f"stance-{name}.png", name=name, feet=feet, sole_sizes=sizes,
                              polygon=st.polygon.vertices, com=st.robot_com, margin_m=st.margin)
        rows.append({"stance": name, "com": st.robot_com, "polygon": st.polygon.vertices,
                     "margin_m": st.margin, "picture": picture})
    return rows


@click.command()
@click.option("--out", "out_dir", default="demo-out", show_default=True, type=click.Path(file_okay=False),
              help="Directory for the demo's artefacts.")
@click.option("--robot", "robot_name", default="hrp5p", show_default=True)
@click.option("--stances-only", is_flag=True, help="Only the first step: solve and draw the stances.")
def demo(out_dir: str, robot_name: str, stances_only: bool) -> None:
    """Run the main job end to end on the embedded defaults and show its result."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    console.rule(f"[bold]regrasp demo[/] -> {out.resolve()}")
    console.print("[bold]1. Robot and stances[/]")
    rows = stance_step(out, robot_name)
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
    if any("error" in r for r in rows):
        fail("some stances could not be solved", code=1)
    console.print(f"[green]done[/]: artefacts in {out.resolve()}")
