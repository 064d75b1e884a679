"""``regrasp paper --out DIR [--quick]``: reproduce the paper's experiments and write DIR/report.md."""

from __future__ import annotations

import time
from pathlib import Path

import click

from .common import console


@click.command()
@click.option("--out", "out_dir", default="paper-out", show_default=True, type=click.Path(file_okay=False))
@click.option("--quick", is_flag=True, help="Small sample counts (minutes, for CI); the full run explores 4,000 states x 3 seeds per "
                   "configuration (the paper's Tables report 1,400-18,000 per configuration).")
@click.option("--workers", type=click.IntRange(1, 64), help="Worker processes per survey (default: one per core).")
@click.option("--no-limits", is_flag=True, help="Do not check joint torques against the effort limits, nor the grip (as the paper).")
def paper(out_dir: str, quick: bool, workers: int | None, no_limits: bool) -> None:
    """Run every simulation of the paper's section IV with our model and write the report."""
    from dataclasses import replace

    from service.paper import PaperSettings, run

    settings = PaperSettings.quick() if quick else PaperSettings.full()
    if workers:
        settings = replace(settings, workers=workers)
    if no_limits:
        settings = replace(settings, limits=False)
    t0 = time.perf_counter()
    res = run(Path(out_dir), settings, progress=lambda m: console.print(f"[dim]{time.perf_counter() - t0:6.1f} s[/] {m}"))
    console.print(f"report: {Path(out_dir, 'report.md').resolve()} (numbers in report.json)")
    for c in res.claims:
        console.print(f"  {c['verdict']:>14}: {c['claim']}")
    console.print(f"total time {time.perf_counter() - t0:.1f} s")
