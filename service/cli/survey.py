"""``regrasp survey``: the task stability survey (CONTRACT.md section 4)."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich.table import Table

from .common import check_scenario_args, console, err_console, fail, mm_to_m
from .plan import run_with_progress

LABELS = {
    "left-left": "Start from left hand - End with left hand",
    "right-right": "Start from right hand - End with right hand",
    "left-right": "Start from left hand - End with right hand",
    "right-left": "Start from right hand - End with left hand",
}


def survey_table(doc: dict, title: str) -> Table:
    table = Table(title=title)
    for col in ("Hand configuration", "C", "U", "R"):
        table.add_column(col, justify="left" if col == "Hand configuration" else "right")
    for row in doc["rows"]:
        mark = " *" if row["hands"] == doc.get("recommended") else ""
        ratio = f"{row['ratio']:.4f}" if row["ratio"] is not None else f"n/a ({row.get('reason') or 'no plan'})"
        table.add_row(LABELS[row["hands"]] + mark, str(row["stable"]), str(row["unstable"]), ratio)
    return table


def _plots(doc: dict, outcomes, directory: Path, prefix: str) -> list[Path]:
    import numpy as np

    from service.plots import plot_survey_bars, plot_survey_scatter

    directory.mkdir(parents=True, exist_ok=True)
    title = f"{doc['stance']['name']}, threshold {doc['threshold_m'] * 1000:.0f} mm"
    paths = [plot_survey_bars(directory / f"{prefix}bars.png", title=f"R per hand configuration ({title})", rows=doc["rows"])]
    with_states = [o for o in outcomes if o.com is not None and len(o.com)]
    if with_states:
        xy = np.vstack([o.com[:, :2] for o in with_states])
        stable = np.concatenate([o.stable_flags for o in with_states])
        paths.append(plot_survey_scatter(directory / f"{prefix}scatter.png", title=f"explored CoM projections ({title})",
                                         polygon=np.array(doc["stats"]["support_polygon"]), threshold_m=doc["threshold_m"],
                                         xy=xy, stable=stable))
    return paths


@click.command()
@click.argument("scenario_file", required=False)
@click.option("--scenario", "scenario_name", help="A built-in scenario name.")
@click.option("--stance", help="Override the scenario's stance.")
@click.option("--threshold-mm", type=float, help="Override the threshold, in millimetres.")
@click.option("--states", type=int, help="Evaluated states per hand configuration (default: the scenario's).")
@click.option("--seed", type=int, help="Random seed (same seed, same counts).")
@click.option("--workers", type=click.IntRange(1, 64), help="Worker processes (default: one per core).")
@click.option("--json", "as_json", is_flag=True, help="Print the survey document as JSON.")
@click.option("--states-out", type=click.Path(dir_okay=False), help="Write every evaluated state to an .npz file.")
@click.option("--all-stances", is_flag=True, help="Run the task in the four built-in stances: a stance x hands matrix of R.")
@click.option("--plot", "plot_dir", type=click.Path(file_okay=False), help="Write the bar chart and CoM scatter to this directory.")
def survey(scenario_file, scenario_name, stance, threshold_mm, states, seed, workers, as_json, states_out, all_stances, plot_dir) -> None:
    """Count stable (C) and unstable (U) explored states per hand configuration; R = C / (C + U)."""
    from planner.jobs import PlanningInputError, resolve_scenario
    from planner.stances import BUILTIN_STANCES
    from planner.survey import run_survey, write_states

    ref = check_scenario_args(scenario_file, scenario_name)
    # With --json, stdout carries the document alone; everything else goes to stderr.
    info = err_console.print if as_json else console.print
    if states is not None and states < 1:
        fail(f"--states must be at least 1, got {states}")
    threshold = mm_to_m("--threshold-mm", threshold_mm)
    if all_stances and stance:
        fail("--all-stances and --stance exclude each other")
    if all_stances and states_out:
        fail("--states-out writes the states of one stance; use it without --all-stances")
    stance_list = BUILTIN_STANCES if all_stances else (stance,)
    docs = []
    try:
        for st in stance_list:
            sc = resolve_scenario(ref, stance=st, threshold_m=threshold, seed=seed,
                                  states_per_configuration=states)
            label = f"survey {sc.name} ({sc.stance if isinstance(sc.stance, str) else sc.stance.name})"
            doc, outcomes = run_with_progress(label, lambda p, sc=sc: run_survey(sc, workers=workers, progress=p))
            docs.append((doc, outcomes))
    except PlanningInputError as exc:
        fail(str(exc))
    except ValueError as exc:
        fail(str(exc))
    if not all_stances:
        reasons = {row.get("reason") for row in docs[0][0]["rows"]}
        if len(reasons) == 1 and "inradius" in (next(iter(reasons)) or ""):
            fail(next(iter(reasons)))  # no state can be stable: nothing was surveyed
    if states_out:
        from planner.robot_model import load_robot

        doc, outcomes = docs[0]
        n = write_states(states_out, doc, outcomes, {"joint_names": list(load_robot(doc["robot"]["name"]).joint_names)})
        info(f"{n} evaluated states written to {Path(states_out).resolve()}", highlight=False)
    if plot_dir:
        for doc, outcomes in docs:
            for path in _plots(doc, outcomes, Path(plot_dir), f"survey-{doc['stance']['name']}-"):
                info(f"plot: {path}")
    if as_json:
        click.echo(json.dumps(docs[0][0] if not all_stances else {"stances": [d for d, _ in docs]}, allow_nan=False))
        return
    for doc, _ in docs:
        console.print(survey_table(doc, f"{doc['stance']['name']} stance, threshold {doc['threshold_m'] * 1000:.0f} mm, "
                                        f"{doc['stats']['states_per_configuration']} states, seed {doc['seed']}"))
        console.print(f"recommended: [bold]{doc['recommended']}[/]  ({doc['stats']['time_s']:.1f} s)")
    if all_stances:
        matrix = Table(title="R by stance and hand configuration")
        matrix.add_column("stance")
        for h in LABELS:
            matrix.add_column(h, justify="right")
        for doc, _ in docs:
            cells = []
            for row in doc["rows"]:
                if row["ratio"] is not None:
                    cells.append(f"{row['ratio']:.3f}")
                elif "inradius" in (row.get("reason") or ""):
                    cells.append("threshold cannot be met")
                else:
                    cells.append("no plan")
            matrix.add_row(doc["stance"]["name"], *cells)
        console.print(matrix)
