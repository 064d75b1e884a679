"""``regrasp simulate PLAN.json``: play a plan in the physics twin (docs/contract.md section 9).

Writes ``DIR/simreport.json`` (``regrasp.simreport/1``), ``DIR/samples.csv`` and, with ``--plot``,
``DIR/cop.png`` (the CoP over the support polygon beside the planned ZMP) and ``DIR/margins.png`` (the margins
over time). Exit 0: the robot stood with no fault; 1: it fell or faulted; 2: bad input.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import click

from .common import console, fail


def _plot(out: Path, result: Any) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = np.array(result.samples, dtype=float)
    if rows.size == 0:
        return
    poly = np.vstack([result.polygon, result.polygon[:1]])
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(poly[:, 0], poly[:, 1], "k-", label="support polygon")
    ax.plot(rows[:, 2], rows[:, 3], "-", color="tab:blue", lw=1, label="planned ZMP")
    ax.plot(rows[:, 4], rows[:, 5], "-", color="tab:red", lw=1, label="simulated CoP")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best")
    ax.set_title("Centre of pressure over the support polygon")
    fig.savefig(out / "cop.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(rows[:, 0], rows[:, 1] * 1000, label="plan: CoM margin")
    ax.plot(rows[:, 0], rows[:, 6] * 1000, label="twin: CoP margin")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("plan time (s)")
    ax.set_ylabel("margin (mm)")
    ax.legend(loc="best")
    fig.savefig(out / "margins.png", dpi=110, bbox_inches="tight")
    plt.close(fig)


def _cell(v: float) -> str:
    return "" if not math.isfinite(v) else repr(float(v))


@click.command("simulate")
@click.argument("plan_file", type=click.Path(dir_okay=False))
@click.option("--speed", type=float, default=1.0, show_default=True,
              help="Play the motion K times faster (a stress test; the physics stays at 1 ms).")
@click.option("--mass-scale", type=float, default=1.0, show_default=True, help="Scale the held object's mass only.")
@click.option("--no-stabilizer", is_flag=True, help="Switch the twin's stabilizer off (position servos only).")
@click.option("--json", "as_json", is_flag=True, help="Also print the report on stdout.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="simulate-out", show_default=True,
              help="Folder for simreport.json, samples.csv and the plots.")
@click.option("--plot", is_flag=True, help="Also write cop.png and margins.png.")
def simulate(plan_file: str, speed: float, mass_scale: float, no_stabilizer: bool, as_json: bool, out_dir: str,
             plot: bool) -> None:
    """Play a plan in the physics twin and report what the robot's feet felt."""
    from pydantic import ValidationError

    from robot_bridge.physics.settings import StabilizerSettings, TwinSettings
    from robot_bridge.physics.simulate import SAMPLE_COLUMNS, SimulateInputError
    from robot_bridge.physics.simulate import simulate as run

    if not (math.isfinite(speed) and 0 < speed <= 20):
        fail(f"--speed must be in (0, 20], got {speed}")
    if not (math.isfinite(mass_scale) and 0 < mass_scale <= 100):
        fail(f"--mass-scale must be in (0, 100], got {mass_scale}")
    try:
        plan = json.loads(Path(plan_file).read_text())
    except OSError as exc:
        fail(f"cannot read {plan_file}: {exc.strerror or exc}")
    except (ValueError, UnicodeDecodeError) as exc:
        fail(f"{plan_file} is not JSON: {exc}")
    try:
        settings = TwinSettings(mass_scale=mass_scale, stabilizer=StabilizerSettings(enabled=not no_stabilizer))
        result = run(plan, settings, speed=speed)
    except (SimulateInputError, ValidationError) as exc:
        fail(f"{plan_file}: {exc}")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "simreport.json").write_text(json.dumps(result.report, indent=2, allow_nan=False) + "\n")
        with open(out / "samples.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(SAMPLE_COLUMNS)
            w.writerows([_cell(v) for v in row] for row in result.samples)
        if plot:
            _plot(out, result)
    except OSError as exc:
        fail(f"cannot write to {out}: {exc.strerror or exc}")
    rep = result.report
    if as_json:
        click.echo(json.dumps(rep, indent=2, allow_nan=False))
    else:
        fault, margin, ratio = rep["fault"], rep["min_cop_margin_m"], rep["cop_margin_ratio"]
        if fault is None:
            verdict = "stood"
        else:
            kind = "FELL" if rep["fell"] else "FAULT"
            verdict = f"{kind} ({fault['kind']} at {fault['at_s']:.2f} s: {fault['detail']})"
        where = "n/a" if margin is None else f"{margin * 1000:.1f} mm at {rep['min_cop_margin_at_s']:.2f} s"
        console.print(f"{verdict}; min CoP margin {where} (ratio {'n/a' if ratio is None else f'{ratio:.2f}'}); "
                      f"stabilizer {'on' if rep['stabilizer'] else 'off'}, speed {speed:g}x, mass x{mass_scale:g}; "
                      f"{rep['wall_s']:.1f} s wall; written to {out}", highlight=False, soft_wrap=True)
    raise SystemExit(0 if result.stood else 1)
