"""``regrasp survey``: the task stability survey (docs/contract.md section 4)."""

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
    for col in ("Hand configuration", "C", "U", "R", "95 % interval", "seeds"):
        table.add_column(col, justify="left" if col == "Hand configuration" else "right")
    ties = set(doc.get("indistinguishable") or [])
    for row in doc["rows"]:
        mark = " *" if row["hands"] == doc.get("recommended") else (" =" if row["hands"] in ties else "")
        ratio = f"{row['ratio']:.4f}" if row["ratio"] is not None else f"n/a ({row.get('reason') or 'no plan'})"
        ci = row.get("ratio_ci95")
        interval = f"[{ci[0]:.4f}, {ci[1]:.4f}]" if ci else "-"
        seeds = f"{row.get('seeds', 0)}{'' if row.get('converged') else ' (not converged)'}" if row["ratio"] is not None else "-"
        table.add_row(LABELS[row["hands"]] + mark, str(row["stable"]), str(row["unstable"]), ratio, interval, seeds)
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


def plot_title(doc: dict, scenario: str | None) -> str:
    """What a survey figure's title names: scenario, stance, threshold, states per configuration."""
    from experiments.plots import describe

    states = (doc.get("stats") or {}).get("states_per_configuration")
    return describe(scenario, doc["stance"]["name"], doc["threshold_m"], states=states) + (" per configuration" if states else "")


def bars_figure(doc: dict, path: Path, scenario: str | None = None) -> Path:
    """The bar chart of R that ``--plot`` writes for a survey document (the recommended row marked)."""
    from experiments.plots import plot_survey_bars

    return plot_survey_bars(path, title=f"stable ratio R per hand configuration\n{plot_title(doc, scenario)}",
                            rows=doc["rows"], recommended=doc.get("recommended"),
                            indistinguishable=doc.get("indistinguishable") or ())


def _plots(doc: dict, outcomes, directory: Path, prefix: str, fmt: str = "png", scenario: str | None = None) -> list[Path]:
    """The bar chart of R; where states were evaluated, the CoM scatter (coloured by configuration) and its CSV data."""
    import numpy as np

    from experiments.convergence_plot import plot_convergence
    from experiments.plots import plot_survey_scatter

    directory.mkdir(parents=True, exist_ok=True)
    title = plot_title(doc, scenario)
    paths = [plot_convergence(directory / f"{prefix}convergence.{fmt}", doc),
             bars_figure(doc, directory / f"{prefix}bars.{fmt}", scenario)]
    hands, xy, stable = scatter_data(outcomes)
    if len(xy):
        paths.append(plot_survey_scatter(directory / f"{prefix}scatter.{fmt}", title=f"explored CoM projections\n{title}",
                                         polygon=np.array(doc["stats"]["support_polygon"]), threshold_m=doc["threshold_m"],
                                         xy=xy, stable=stable, hands=hands))
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


def ray_seed_map(address: str):  # type: ignore[no-untyped-def]
    """The seed map of the Ray cluster at ``address``, or exit 2 saying why there is none."""
    try:
        from service.executors.ray_seeds import RaySeeds, connect

        connect(address)
        return RaySeeds()
    except ImportError:
        fail("--ray-address needs Ray: pip install 'hrp-regrasp[ray]'")
    except (ConnectionError, RuntimeError, ValueError) as exc:
        fail(f"cannot join the Ray cluster at {address}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
    return None


@click.command()
@click.argument("scenario_file", required=False)
@click.option("--scenario", "scenario_name", help="A built-in scenario name.")
@click.option("--stance", help="Override the scenario's stance.")
@click.option("--threshold-mm", type=float, help="Override the threshold, in millimetres.")
@click.option("--until", type=click.Choice(["solved", "states"]), help="solved: seeds explore until they reach the goal, "
              "repeated until the intervals are tight; states: a fixed number of states per seed (--states).")
@click.option("--states", type=int, help="States counted per seed (implies --until states).")
@click.option("--ci-half-width", type=float, help="Largest distance of the 95 % bounds from R (default 0.02).")
@click.option("--seeds-min", type=int, help="Fewest seeds per configuration (default 10).")
@click.option("--seeds-max", type=int, help="Most seeds per configuration (default 256).")
@click.option("--seed", type=int, help="First seed (seeds seed, seed + 1, ...; same seed, same counts).")
@click.option("--no-limits", is_flag=True, help="Effort and grip checks off, as in the paper: a pose over a joint's effort "
              "limit or slipping in the grip is then not counted unstable.")
@click.option("--robot", "robot_ref", help="Override the scenario's robot: a name (`regrasp robot list`) or a robot spec file.")
@click.option("--workers", type=click.IntRange(1, 64), help="Worker processes (default: one per core).")
@click.option("--ray-address", help="An existing Ray cluster (host:port, or auto): the seeds run there as tasks "
              "spread over its nodes (RAY_AUTH_MODE=token when the cluster uses token auth).")
@click.option("--json", "as_json", is_flag=True, help="Print the survey document as JSON.")
@click.option("--states-out", type=click.Path(dir_okay=False), help="Write every evaluated state to an .npz file.")
@click.option("--all-stances", is_flag=True, help="Run the task in the four built-in stances: a stance x hands matrix of R.")
@click.option("--plot", "plot_dir", type=click.Path(file_okay=False),
              help="Write the convergence plot (R against states counted, with its interval), the bar chart and the CoM scatter here.")
@click.option("--format", "fmt", type=click.Choice(["png", "svg", "pdf"]), default="png", show_default=True,
              help="Format of the --plot figures.")
def survey(scenario_file, scenario_name, stance, threshold_mm, until, states, ci_half_width, seeds_min, seeds_max, seed,
           no_limits, robot_ref, workers, ray_address, as_json, states_out, all_stances, plot_dir, fmt) -> None:
    """Count stable (C) and unstable (U) explored states per hand configuration; R = C / (C + U)."""
    from planner.api.catalogue import BUILTIN_STANCES, resolve_scenario
    from planner.api.jobs import SurveyCache, run_survey, scenario_for_robot, write_states
    from planner.errors import InputError

    ref = check_scenario_args(scenario_file, scenario_name)
    # With --json, stdout carries the document alone; everything else goes to stderr. File paths are
    # printed unwrapped (soft_wrap) so they can be copied whatever the terminal's width.
    info = err_console.print if as_json else console.print
    if states is not None and states < 1:
        fail(f"--states must be at least 1, got {states}")
    if until == "states" and states is None:
        fail("--until states needs --states N")
    if until == "solved" and states is not None:
        fail("--states is the fixed budget of --until states; leave it out with --until solved")
    for flag, value in (("--seeds-min", seeds_min), ("--seeds-max", seeds_max)):
        if value is not None and value < 1:
            fail(f"{flag} must be at least 1, got {value}")
    if ci_half_width is not None and not 0 < ci_half_width <= 0.5:
        fail(f"--ci-half-width must be in (0, 0.5], got {ci_half_width}")
    overrides = {"until": "states" if states is not None else until, "states_per_seed": states,
                 "ci_half_width": ci_half_width, "seeds_min": seeds_min, "seeds_max": seeds_max}
    overrides = {k: v for k, v in overrides.items() if v is not None} or None
    threshold = mm_to_m("--threshold-mm", threshold_mm)
    if all_stances and stance:
        fail("--all-stances and --stance exclude each other")
    if all_stances and states_out:
        fail("--states-out writes the states of one stance; use it without --all-stances")
    stance_list = BUILTIN_STANCES if all_stances else (stance,)
    seed_map = ray_seed_map(ray_address) if ray_address else None
    docs = []
    names: list[str] = []
    try:
        for st in stance_list:
            sc = resolve_scenario(ref, stance=st, threshold_m=threshold, seed=seed, survey=overrides)
            # a built-in task run with another robot is fitted to it, where `plan` and the service fit it
            sc = scenario_for_robot(sc, robot_ref)
            label = f"survey {sc.name} ({sc.stance if isinstance(sc.stance, str) else sc.stance.name})"
            want_states = bool(states_out or plot_dir)
            cache = SurveyCache.default()

            def job(p, sc=sc, want_states=want_states, cache=cache):
                if want_states:  # the states are not cached: run, and store the answer for the task
                    doc, outcomes = run_survey(sc, workers=workers, progress=p, no_limits=no_limits, seed_map=seed_map)
                    cache.put(cache.key_for(sc, limits=not no_limits), doc)
                    return doc, outcomes
                return cache.get_or_run(sc, lambda: run_survey(sc, workers=workers, progress=p, keep_states=False,
                                                               no_limits=no_limits, seed_map=seed_map)[0],
                                        limits=not no_limits), []

            doc, outcomes = run_with_progress(label, job)
            doc["stats"]["no_limits"] = no_limits
            docs.append((doc, outcomes))
            names.append(sc.name)
    except InputError as exc:
        fail(str(exc))
    except ValueError as exc:
        fail(str(exc))
    if seed_map is not None and seed_map.placements:
        from collections import Counter

        per_node = Counter(node for _, _, node in seed_map.placements)
        info(f"Ray: {len(seed_map.placements)} seeds ran on {len(per_node)} node(s): "
             + ", ".join(f"{node} ({n})" for node, n in sorted(per_node.items())), highlight=False, soft_wrap=True)
    if not all_stances:
        reasons = {row.get("reason") for row in docs[0][0]["rows"]}
        if len(reasons) == 1 and "inradius" in (next(iter(reasons)) or ""):
            fail(next(iter(reasons)))  # no state can be stable: nothing was surveyed
    if states_out:
        from planner.api.robots import load_robot

        doc, outcomes = docs[0]
        n = write_states(states_out, doc, outcomes, {"joint_names": list(load_robot(doc["robot"]["name"]).joint_names)})
        info(f"{n} evaluated states written to {Path(states_out).resolve()}", highlight=False, soft_wrap=True)
    if plot_dir:
        for (doc, outcomes), name in zip(docs, names):
            for path in _plots(doc, outcomes, Path(plot_dir), f"survey-{doc['stance']['name']}-", fmt, scenario=name):
                info(f"plot: {path}", highlight=False, soft_wrap=True)
    if as_json:
        click.echo(json.dumps(docs[0][0] if not all_stances else {"stances": [d for d, _ in docs]}, allow_nan=False))
        return
    for doc, _ in docs:
        est = doc.get("estimator") or {}
        budget = (f"{est.get('states_per_seed')} states per seed" if est.get("until") == "states"
                  else f"seeds until +-{est.get('ci_half_width')}")
        console.print(survey_table(doc, f"{doc['stance']['name']} stance, threshold {doc['threshold_m'] * 1000:.0f} mm, "
                                        f"{budget}, seeds from {doc['seed']}{', no limits' if no_limits else ''}"))
        ties = doc.get("indistinguishable") or []
        console.print(f"recommended: [bold]{doc['recommended']}[/]"
                      + (f" (a tie with {', '.join(ties)}: overlapping intervals)" if ties else "")
                      + f"  ({doc['stats']['time_s']:.1f} s{', cached' if doc['stats'].get('cache') == 'hit' else ''})")
    if all_stances:
        console.print(stance_matrix([doc for doc, _ in docs]))
