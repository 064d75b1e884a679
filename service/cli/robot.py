"""``regrasp robot list | urdf NAME | info NAME [--json]``."""

from __future__ import annotations

import click
from rich.table import Table

from .common import console, fail, print_json


@click.group()
def robot() -> None:
    """Robot models: list them, print a URDF path, describe one."""


@robot.command("list")
def list_robots() -> None:
    """Print the available robots, one per line."""
    from planner.robot.registry import DEFAULT_ROBOT, load_spec, robot_names

    for name in robot_names():
        mark = " (default)" if name == DEFAULT_ROBOT else ""
        click.echo(f"{name}{mark}\t{load_spec(name).description}")


@robot.command("urdf")
@click.argument("name")
def urdf(name: str) -> None:
    """Print the absolute path of NAME's URDF (loads in pinocchio with a free-flyer root)."""
    from planner.robot.registry import UnknownRobotError, urdf_path

    try:
        click.echo(str(urdf_path(name)))
    except UnknownRobotError as exc:
        fail(str(exc))


@robot.command("info")
@click.argument("name", default="hrp5p")
@click.option("--json", "as_json", is_flag=True, help="Print machine-readable JSON.")
def info(name: str, as_json: bool) -> None:
    """Describe a robot: mass, height, joints, limits and built-in stances."""
    from planner.robot.info import robot_info
    from planner.robot.model import load_robot
    from planner.robot.registry import UnknownRobotError

    try:
        doc = robot_info(load_robot(name))
    except UnknownRobotError as exc:
        fail(str(exc))
    if as_json:
        print_json(doc)
        return
    console.print(f"[bold]{doc['name']}[/]: {doc['description']}")
    console.print(f"URDF {doc['urdf']}\nsha256 {doc['urdf_sha256']}")
    console.print(f"mass {doc['total_mass_kg']:.2f} kg, height {doc['height_m']:.3f} m, {doc['dof']} DoF")
    table = Table("joint", "lower rad", "upper rad", "vel rad/s", "acc rad/s^2")
    for j in doc["joint_names"]:
        lo, hi = doc["position_limits"][j]
        table.add_row(j, f"{lo:.3f}", f"{hi:.3f}", f"{doc['velocity_limits'][j]:.2f}", f"{doc['acceleration_limits'][j]:.2f}")
    console.print(table)
    st = Table("stance", "CoM x, y, z (m)", "margin (mm)")
    for s in doc["stances"]:
        if "error" in s:
            st.add_row(s["name"], "-", s["error"])
        else:
            st.add_row(s["name"], ", ".join(f"{v:.3f}" for v in s["com"]), f"{s['margin_m'] * 1000:.1f}")
    console.print(st)
    console.print(f"[dim]{doc['limit_sources']}[/]")
