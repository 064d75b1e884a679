"""The survey's convergence: R against the states counted so far, per configuration, with its interval.

The series is recomputed from a survey document's ``per_seed`` counts (seeds in the order they
were judged), with the same seeded bootstrap the estimator used, so the last point of each
curve is the row's ``ratio`` and ``ratio_ci95``. One PNG per survey (per stance).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from planner.api.jobs import bootstrap_rng, ratio_interval  # noqa: E402

from .plots import HANDS_COLOURS  # noqa: E402 - one colour per hand configuration in every plot



def convergence_series(row: dict[str, Any], first_seed: int) -> dict[str, np.ndarray]:
    """After each seed: states counted so far, pooled R, and the 95 % interval's bounds."""
    per_seed = row.get("per_seed") or []
    c = np.array([p["stable"] for p in per_seed], dtype=float)
    u = np.array([p["unstable"] for p in per_seed], dtype=float)
    strata = [(p.get("key_path") or {}).get("seed") for p in per_seed]  # the estimator's strata: key paths
    states, ratio, lo, hi = [], [], [], []
    for k in range(1, len(per_seed) + 1):
        n = c[:k].sum() + u[:k].sum()
        if n <= 0:
            continue
        interval = ratio_interval(c[:k], u[:k], bootstrap_rng(first_seed, row["hands"], k), strata=strata[:k])
        states.append(n)
        ratio.append(c[:k].sum() / n)
        lo.append(interval[0])
        hi.append(interval[1])
    return {"states": np.array(states), "ratio": np.array(ratio), "lo": np.array(lo), "hi": np.array(hi)}


def plot_convergence(path: Path, doc: dict[str, Any], title: str | None = None) -> Path:
    """R against the states counted so far, one curve and band per configuration."""
    fig, ax = plt.subplots(figsize=(7, 4))
    hw = (doc.get("estimator") or {}).get("ci_half_width")
    for row in doc["rows"]:
        s = convergence_series(row, int(doc["seed"]))
        if not len(s["states"]):
            continue
        colour = HANDS_COLOURS.get(row["hands"], "k")
        label = f"{row['hands']}: R = {row['ratio']:.3f} ({row['seeds']} seeds{', converged' if row.get('converged') else ''})"
        ax.plot(s["states"], s["ratio"], "-o", ms=2, color=colour, label=label)
        ax.fill_between(s["states"], s["lo"], s["hi"], color=colour, alpha=0.15)
    ax.set_xscale("log")
    ax.set_xlabel("states counted so far (all seeds)")
    ax.set_ylabel("R = C / (C + U), 95 % interval")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(title or f"{doc['stance']['name']}: convergence of R" + (f" (target +-{hw:g})" if hw else ""))
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=7)
    else:
        ax.text(0.5, 0.5, "no configuration has a ratio", ha="center", va="center", transform=ax.transAxes)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
