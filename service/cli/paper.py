"""``regrasp paper --out DIR [--quick]``: reproduce the paper's experiments and write DIR/report.md."""

from __future__ import annotations

import time
from pathlib import Path

import click

from .common import console


@click.command()
@click.option("--out", "out_dir", default="paper-out", show_default=True, type=click.Path(file_okay=False))
@click.option("--quick", is_flag=True, help="Small sample counts (for CI: 150 states x 4 seeds per "
              "configuration, one key path each); the full run repeats seeds until every interval is within +-0.02.")
@click.option("--no-limits", is_flag=True, help="Leave out the section that runs the surveys and plans again with effort "
              "and grip checked (the reproduction is always without them, as the paper had none).")
@click.option("--workers", type=click.IntRange(1, 64), help="Worker processes per survey (default: one per core).")
@click.option("--ray-address", help="An existing Ray cluster (host:port, or auto): every survey's seeds run there as "
              "tasks spread over its nodes.")
def paper(out_dir: str, quick: bool, no_limits: bool, workers: int | None, ray_address: str | None) -> None:
    """Run every simulation of the paper's section IV with our model and write the report."""
    from dataclasses import replace

    from experiments.paper import PaperSettings, run

    settings = PaperSettings.quick_run() if quick else PaperSettings.full()
    settings = replace(settings, no_limits=True)  # the paper's tables had no effort or grip limits
    if no_limits:
        settings = replace(settings, limits_section=False)
    if workers:
        settings = replace(settings, workers=workers)
    if ray_address:
        from .survey import ray_seed_map

        settings = replace(settings, seed_map=ray_seed_map(ray_address))
    t0 = time.perf_counter()
    res = run(Path(out_dir), settings, progress=lambda m: console.print(f"[dim]{time.perf_counter() - t0:6.1f} s[/] {m}"))
    console.print(f"report: {Path(out_dir, 'report.md').resolve()} (numbers in report.json)")
    for c in res.claims:
        console.print(f"  {c['verdict']:>14}: {c['id']}" + (f" (cause: {c['cause']}; changed, it is {c['cause_run']['verdict']})"
                                                          if c.get("cause_run") else ""))
    console.print(f"total time {time.perf_counter() - t0:.1f} s")
