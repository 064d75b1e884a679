"""``regrasp survey``: the task stability survey (CONTRACT.md section 4)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.table import Table

from .common import check_scenario_args, console, err_console, fail, mm_to_m
from .plan import run_with_progress

if TYPE_CHECKING:
    import numpy as np

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


def scatter_data(outcomes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the CoM scatter draws: hands (N,), CoM ground projections (N, 2), stable (N,).

    In evaluation order, configuration by configuration: the order of ``--states-out``.
    """
    import numpy as np

    with_states = [o for o in outcomes if o.com is not None and len(o.com)]
    if not with_states:
        return np.zeros(0, "U11"), np.zeros((0, 2)), np.zeros(0, bool)
    hands = np.concatenate([np.full(len(o.com), o.hands) for o in with_states]).astype("U11")
    xy = np.vstack([o.com[:, :2] for o in with_states])
    stable = np.concatenate([o.stable_flags for o in with_states]).astype(bool)
    return hands, xy, stable


def write_scatter_csv(path: Path, hands: np.ndarray, xy: np.ndarray, stable: np.ndarray) -> Path:
    """The scatter's points as CSV (hands, x_m, y_m, stable), so the picture can be checked or redrawn."""
    with open(path, "w", encoding="utf-8", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["hands", "x_m", "y_m", "stable"])
        for h, (x, y), s in zip(hands, xy, stable):
            writer.writerow([h, repr(float(x)), repr(float(y)), int(bool(s))])
    return path


def _plots(doc: dict, outcomes, directory: Path, prefix: str) -> list[Path]:
    """The bar chart of R; where states were evaluated, the CoM scatter and its CSV data."""
    import numpy as np

    from service.plots import plot_survey_bars, plot_survey_scatter

    directory.mkdir(parents=True, exist_ok=True)
    title = f"{doc['stance']['name']}, threshold {doc['threshold_m'] * 1000:.0f} mm"
    paths = [plot_survey_bars(directory / f"{prefix}bars.png", title=f"R per hand configuration ({title})", rows=doc["rows"])]
    hands, xy, stable = scatter_data(outcomes)
    if len(xy):
        paths.append(plot_survey_scatter(directory / f"{prefix}scatter.png", title=f"explored CoM projections ({title})",
                                         polygon=np.array(doc["stats"]["support_polygon"]), threshold_m=doc["threshold_m"],
                                         xy=xy, stable=stable))
        paths.append(write_scatter_csv(directory / f"{prefix}scatter.csv", hands, xy, stable))
    return paths


def _cell(row: dict | None) -> str:
    if row is None:
        return "not surveyed"
    if row["ratio"] is not None:
        return f"{row['ratio']:.3f}"
    if "inradius" in (row.get("reason") or ""):
        return "threshold cannot be met"
    return "no plan"


def stance_matrix(docs: list[dict]) -> Table:
    """The stance x hands matrix of R (the paper's comparison of stances), one row per survey document."""
    matrix = Table(title="R by stance and hand configuration")
    matrix.add_column("stance")
    for h in LABELS:
        matrix.add_column(h, justify="right")
    for doc in docs:
        by_hands = {row["hands"]: row for row in doc["rows"]}
        matrix.add_row(doc["stance"]["name"], *(_cell(by_hands.get(h)) for h in LABELS))
    return matrix


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
@click.option("--no-limits", is_flag=True, help="Do not check joint torques against the effort limits, nor the grip (as the paper).")
def survey(scenario_file, scenario_name, stance, threshold_mm, states, seed, workers, as_json, states_out, all_stances, plot_dir,
           no_limits) -> None:
    """Count stable (C) and unstable (U) explored states per hand configuration; R = C / (C + U)."""
    from planner.errors import InputError
    from planner.scene.scenarios import resolve_scenario
    from planner.stability.stances import BUILTIN_STANCES
    from planner.survey.runner import run_survey, write_states

    ref = check_scenario_args(scenario_file, scenario_name)
    # With --json, stdout carries the document alone; everything else goes to stderr. File paths are
    # printed unwrapped (soft_wrap) so they can be copied whatever the terminal's width.
    info = err_console.print if as_json else console.print
    if states is not None and states < 1:
        fail(f"--states must be at least 1, got {states}")
    threshold = mm_to_m("--threshold-mm", threshold_mm)
    if all_stances and stance:
        fail("--all-stances and --stance exclude each other")
    if all_stances and states_out:
        fail("--states-out writes the states of one stance; use it without --all-stances")
    stance_list = BUILTIN_STANCES if all_stances else (stance,)
    from planner.regrasp.settings import PlannerSettings

    settings = PlannerSettings(limits=False) if no_limits else None
    docs = []
    try:
        for st in stance_list:
            sc = resolve_scenario(ref, stance=st, threshold_m=threshold, seed=seed,
                                  states_per_configuration=states)
            label = f"survey {sc.name} ({sc.stance if isinstance(sc.stance, str) else sc.stance.name})"
            doc, outcomes = run_with_progress(label, lambda p, sc=sc: run_survey(sc, workers=workers, progress=p,
                                                                                      settings=settings))
            docs.append((doc, outcomes))
    except InputError as exc:
        fail(str(exc))
    except ValueError as exc:
        fail(str(exc))
    if not all_stances:
        reasons = {row.get("reason") for row in docs[0][0]["rows"]}
        if len(reasons) == 1 and "inradius" in (next(iter(reasons)) or ""):
            fail(next(iter(reasons)))  # no state can be stable: nothing was surveyed
    if states_out:
        from planner.robot.model import load_robot

        doc, outcomes = docs[0]
        n = write_states(states_out, doc, outcomes, {"joint_names": list(load_robot(doc["robot"]["name"]).joint_names)})
        info(f"{n} evaluated states written to {Path(states_out).resolve()}", highlight=False, soft_wrap=True)
    if plot_dir:
        for doc, outcomes in docs:
            for path in _plots(doc, outcomes, Path(plot_dir), f"survey-{doc['stance']['name']}-"):
                info(f"plot: {path}", highlight=False, soft_wrap=True)
    if as_json:
        click.echo(json.dumps(docs[0][0] if not all_stances else {"stances": [d for d, _ in docs]}, allow_nan=False))
        return
    for doc, _ in docs:
        console.print(survey_table(doc, f"{doc['stance']['name']} stance, threshold {doc['threshold_m'] * 1000:.0f} mm, "
                                        f"{doc['stats']['states_per_configuration']} states, seed {doc['seed']}"))
        console.print(f"recommended: [bold]{doc['recommended']}[/]  ({doc['stats']['time_s']:.1f} s)")
    if all_stances:
        console.print(stance_matrix([doc for doc, _ in docs]))
