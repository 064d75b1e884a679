"""``regrasp plan``: plan a regrasp task and write the plan file (docs/contract.md section 3)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import click
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from .common import check_scenario_args, console, fail, mm_to_m

HANDS = click.Choice(["auto", "left-left", "right-right", "left-right", "right-left"])


def run_with_progress(label: str, fn):
    """Run fn(progress_callback) under a rich progress bar.

    The bar is redrawn by the callback, not by rich's refresh thread: the process stays
    single-threaded, so the survey can fork its worker processes (see planner.survey.runner).
    """
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), TextColumn("{task.fields[msg]}"), console=console, transient=True,
                  auto_refresh=False) as bar:
        task = bar.add_task(label, total=1.0, msg="")

        def progress(fraction: float, message: str) -> None:
            bar.update(task, completed=min(max(fraction, 0.0), 1.0), msg=message[:70])
            bar.refresh()

        return fn(progress)


def summary_table(plans: list[tuple[str, dict]]) -> Table:
    """One column per plan: hands, cost, min margin, regrasps, duration, time spent, failures by cause."""
    table = Table()
    table.add_column("")
    for label, _ in plans:
        table.add_column(label)
    rows: dict[str, list[str]] = {k: [] for k in ("status", "hands", "cost", "min margin (mm)", "threshold (mm)",
                                                    "regrasps", "handovers", "duration (s)", "planning time (s)", "failures by cause")}
    for _, plan in plans:
        st = plan.get("stats", {})
        segs = plan.get("segments", [])
        traj = plan.get("trajectory", [])
        handovers = sum(1 for s in segs if s["kind"] == "handover") // 2
        # A pick from the table has two approach segments (to the grasp, close the jaw); a handover one.
        picks = (sum(1 for s in segs if s["kind"] == "approach") - handovers) // 2
        failures = st.get("failures") or (plan.get("failure") or {}).get("counts", {})
        rows["status"].append(plan["status"] if plan["status"] == "solved" else f"infeasible ({plan['failure']['code']})")
        rows["hands"].append(str(plan.get("hands")))
        rows["cost"].append(f"{st['cost']:.3f}" if st.get("cost") is not None else "-")
        rows["min margin (mm)"].append(f"{plan['min_margin_m'] * 1000:.1f}" if plan.get("min_margin_m") is not None else "-")
        rows["threshold (mm)"].append(f"{plan['threshold_m'] * 1000:.0f}")
        rows["regrasps"].append(str(max(picks - 1, 0)) if traj else "-")
        rows["handovers"].append(str(handovers) if traj else "-")
        rows["duration (s)"].append(f"{traj[-1]['t']:.2f}" if traj else "-")
        rows["planning time (s)"].append(f"{st.get('time_s') or 0:.2f}")
        rows["failures by cause"].append(", ".join(f"{k}={v}" for k, v in sorted(failures.items())) or "none")
    for key, values in rows.items():
        table.add_row(key, *values)
    return table


def plot_plan(plan: dict, path: Path, compare: dict | None = None) -> list[Path]:
    """The CoM ground trace over the support polygon at ``path``, and beside it (``*-margin``) the margin
    over time with the pick and place moments marked; the format follows the path's suffix."""
    import numpy as np

    from experiments.plots import (
        describe,
        holding_events,
        plot_com_trace,
        plot_margin_over_time,
    )

    traces, margins = [], []
    for doc, colour in ((plan, "tab:blue"), (compare, "tab:red")):
        if doc is not None and doc["status"] == "solved":
            label = f"plan at {doc['threshold_m'] * 1000:g} mm"
            traces.append((label, np.array([p["com"][:2] for p in doc["trajectory"]]), colour))
            margins.append((label, np.array([p["t"] for p in doc["trajectory"]]),
                            np.array([p["margin_m"] for p in doc["trajectory"]]), colour))
    head = describe(plan["scenario"]["name"], plan["stance"]["name"], plan["threshold_m"], hands=plan.get("hands"))
    path = Path(path)
    out = [plot_com_trace(path, title=f"CoM ground trace\n{head}", polygon=np.array(plan["support_polygon"]),
                          threshold_m=plan["threshold_m"], traces=traces)]
    if margins:
        out.append(plot_margin_over_time(path.with_name(path.stem + "-margin" + path.suffix), title=f"CoM margin over time\n{head}",
                                         threshold_m=plan["threshold_m"], traces=margins,
                                         events=holding_events(plan["trajectory"])))
    return out


def plan_summary(plan: dict, path: Path | None = None) -> dict:
    """What ``plan --json`` prints: the plan's headline figures (the plan itself is in the --out file)."""
    traj = plan.get("trajectory") or []
    st = plan.get("stats") or {}
    return {"status": plan["status"], "failure": plan.get("failure"), "scenario": plan["scenario"]["name"],
            "stance": plan["stance"]["name"], "hands": plan.get("hands"), "threshold_m": plan["threshold_m"],
            "min_margin_m": plan.get("min_margin_m"),
            "headroom_m": plan["min_margin_m"] - plan["threshold_m"] if plan.get("min_margin_m") is not None else None,
            "points": len(traj), "duration_s": traj[-1]["t"] if traj else None, "segments": len(plan.get("segments") or []),
            "planning_time_s": st.get("time_s"), "failures": st.get("failures") or {},
            "survey_recommendation": st.get("survey_recommendation"),
            "plan_file": str(path.resolve()) if path is not None else None}


@click.command()
@click.argument("scenario_file", required=False)
@click.option("--scenario", "scenario_name", help="A built-in scenario name (see `regrasp scenario list`).")
@click.option("--stance", help="Override the scenario's stance (built-in name or stance YAML).")
@click.option("--threshold-mm", type=float, help="Override the CoM margin threshold, in millimetres (0 = unconstrained).")
@click.option("--hands", type=HANDS, help="Hand configuration, or auto (chosen by the stability survey).")
@click.option("--seed", type=int, help="Random seed (same seed, same plan).")
@click.option("--solutions", type=click.IntRange(1, 20), default=1, show_default=True, help="Keep the K best solutions.")
@click.option("--time-limit-s", type=float, help="Safety-net time limit in seconds.")
@click.option("--speed-scale", type=float, help="Share of the time-optimal speed (0 < S <= 1; default the scenario's, 1).")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False), help="Where to write the plan JSON.")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False),
              help="Write the CoM trace over the support polygon here, and the margin over time beside it (*-margin).")
@click.option("--format", "fmt", type=click.Choice(["png", "svg", "pdf"]),
              help="Figure format of --plot (default: the path's suffix, else png).")
@click.option("--compare-threshold-mm", type=float, help="Also plan at this threshold (e.g. 0) and overlay it on the plot.")
@click.option("--json", "as_json", is_flag=True, help="Print the plan's summary as JSON on stdout (the plan goes to --out).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("--no-limits", is_flag=True, help="Do not check joint torques against the effort limits, nor the grip (as the paper).")
@click.option("--robot", "robot_ref", help="Override the scenario's robot: a name (`regrasp robot list`) or a robot spec file.")
@click.option("--mass-kg", type=float, help="Override the object's mass, kg (a built-in task fitted to another robot "
              "gets a mass within that robot's reach; this overrides it too).")
def plan(scenario_file, scenario_name, stance, threshold_mm, hands, seed, solutions, time_limit_s, speed_scale, out_path,
         plot_path, fmt, compare_threshold_mm, as_json, quiet, no_limits, robot_ref, mass_kg) -> None:
    """Plan a regrasp task: pick, regrasp or hand over, and place, keeping the CoM margin."""
    from planner.api.catalogue import resolve_scenario
    from planner.api.jobs import PlanOptions, plan_scenario
    from planner.errors import InputError

    ref = check_scenario_args(scenario_file, scenario_name)
    threshold_m = mm_to_m("--threshold-mm", threshold_mm)
    compare_m = mm_to_m("--compare-threshold-mm", compare_threshold_mm)
    if speed_scale is not None and not (math.isfinite(speed_scale) and 0.0 < speed_scale <= 1.0):
        fail(f"--speed-scale must be a number with 0 < S <= 1 (the share of the time-optimal speed), got {speed_scale}")
    try:
        sc = resolve_scenario(ref)
        options = PlanOptions(hands=hands, threshold_m=threshold_m, seed=seed, solutions=solutions, stance=stance,
                              time_limit_s=time_limit_s, limits=not no_limits, robot=robot_ref, mass_kg=mass_kg,
                              speed_scale=speed_scale)
        t0 = time.perf_counter()
        if quiet or as_json:
            doc = plan_scenario(sc, options)
        else:
            doc = run_with_progress("planning", lambda p: plan_scenario(sc, options, progress=p))
        compare = None
        if compare_m is not None:
            opts2 = PlanOptions(hands=doc.get("hands") or hands, threshold_m=compare_m, seed=seed,
                                stance=stance, time_limit_s=time_limit_s, limits=not no_limits, robot=robot_ref,
                                mass_kg=mass_kg, speed_scale=speed_scale)
            compare = (plan_scenario(sc, opts2) if quiet or as_json else
                       run_with_progress("comparison", lambda p: plan_scenario(sc, opts2, progress=p)))
    except InputError as exc:
        fail(str(exc))
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    Path(out_path).write_text(json.dumps(doc, allow_nan=False))
    figures: list[Path] = []
    if plot_path:
        from experiments.plots import with_format

        target = with_format(plot_path, fmt or (None if Path(plot_path).suffix else "png"))
        target.parent.mkdir(parents=True, exist_ok=True)
        figures = plot_plan(doc, target, compare)
    if as_json:
        summary = plan_summary(doc, Path(out_path))
        summary["figures"] = [str(f.resolve()) for f in figures]
        if compare is not None:
            summary["compare"] = plan_summary(compare)
        click.echo(json.dumps(summary, allow_nan=False))
        if doc["status"] != "solved":
            raise SystemExit(1)
        return
    plans = [(f"{sc.name}", doc)]
    if compare is not None:
        plans.append((f"at {compare_threshold_mm:g} mm", compare))
    console.print(summary_table(plans))
    said = (doc.get("stats") or {}).get("survey_recommendation")
    if said:  # hands: auto followed the task's survey: its recommendation with the interval, the seeds and the ties
        console.print(f"survey (hands: auto): {said.get('text') or said.get('recommended')}", highlight=False)
    if doc["status"] != "solved":
        console.print(f"[yellow]infeasible[/] ({doc['failure']['code']}): {doc['failure']['message']}")
    for figure in figures:
        console.print(f"plot: {figure}", highlight=False, soft_wrap=True)
    console.print(f"plan written to {Path(out_path).resolve()} ({time.perf_counter() - t0:.1f} s)")
    if doc["status"] != "solved":
        raise SystemExit(1)
