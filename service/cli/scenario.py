"""``regrasp scenario list | show NAME | check FILE``."""

from __future__ import annotations

import click
import yaml

from .common import console, fail, print_json


@click.group()
def scenario() -> None:
    """Built-in scenarios and scenario files (schema regrasp.scenario/1)."""


@scenario.command("list")
@click.option("--json", "as_json", is_flag=True, help="Print the list as JSON (one object per scenario).")
def list_scenarios(as_json: bool) -> None:
    """Print the built-in scenarios with their stance, object and threshold."""
    from planner.api.catalogue import builtin_names, load_builtin

    entries = []
    for name in builtin_names():
        sc = load_builtin(name)
        stance = sc.stance if isinstance(sc.stance, str) else sc.stance.name
        entries.append({"name": name, "robot": sc.robot, "stance": stance, "object": {"shape": sc.object.shape,
                        "mass_kg": sc.object.mass_kg}, "threshold_m": sc.threshold_m, "hands": sc.hands, "seed": sc.seed})
        if as_json:
            continue
        click.echo(
            f"{name}\tstance={stance}\tobject={sc.object.shape} {sc.object.mass_kg:g} kg\t"
            f"threshold={sc.threshold_m * 1000:g} mm\thands={sc.hands}"
        )
    if as_json:
        print_json(entries)


@scenario.command("show")
@click.argument("name")
def show(name: str) -> None:
    """Print a built-in scenario (or a scenario file) as resolved YAML."""


    from planner.api.catalogue import ScenarioError, load_scenario

    try:
        sc = load_scenario(name)
    except ScenarioError as exc:
        fail(str(exc))
    from planner.api.catalogue import portable_dump

    # Meshes by registered name or as the file wrote them: the printed scenario works saved anywhere.
    click.echo(yaml.safe_dump(portable_dump(sc, by_alias=True, exclude_none=True), sort_keys=False))


def unknown_names(sc) -> list[str]:  # type: ignore[no-untyped-def]
    """The scenario's robot and stance names that are not registered (a stance file that exists counts as known)."""
    from pathlib import Path

    from planner.api.catalogue import is_spec_path, registered_robots, registered_stances

    out = []
    # on the command line a robot spec file is taken by its path, as `plan` takes it (the service takes names only)
    if not is_spec_path(sc.robot) and sc.robot not in registered_robots():
        out.append(f"unknown robot {sc.robot!r}; valid robots: {', '.join(registered_robots())}")
    if isinstance(sc.stance, str) and sc.stance not in registered_stances() and not Path(sc.stance).is_file():
        out.append(f"unknown stance {sc.stance!r}; built-in stances: {', '.join(registered_stances())} (or a stance file)")
    return out


@scenario.command("check")
@click.argument("file")
def check(file: str) -> None:
    """Validate a scenario file (or built-in name): schema, robot, stance, threshold, object, start/goal.

    Exit codes: 0 valid, 1 it cannot be planned as written, 2 unreadable or an unknown name.
    """
    from planner.api.catalogue import ScenarioError, check_scenario, load_scenario

    try:
        sc = load_scenario(file)
    except ScenarioError as exc:
        fail(str(exc))
    unknown = unknown_names(sc)
    if unknown:
        fail("; ".join(unknown))
    from planner.errors import InputError

    try:
        report = check_scenario(sc)
    except InputError as exc:  # a robot spec file that cannot be used
        fail(str(exc))
    for note in report.notes:
        console.print(f"[dim]{note}[/]")
    if not report.ok:
        fail("\n".join(report.problems), code=1)
    console.print(f"[green]ok[/]: scenario {sc.name!r} is valid")
