"""Pictures: stances, CoM traces over the support polygon, survey charts.

Matplotlib with the Agg backend (no display needed). Every function writes one PNG
and returns its path.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon as MplPolygon  # noqa: E402


def _save(fig, ax, path: Path, title: str, *, legend: bool = True, grid: bool = True) -> Path:
    """Title, legend, grid, layout, write the PNG and free the figure."""
    ax.set_title(title)
    if legend:
        ax.legend(loc="best", fontsize=7)
    if grid:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def shrink_polygon(vertices: np.ndarray, distance: float) -> np.ndarray | None:
    """The polygon shrunk inward by ``distance`` (the region where margin >= distance), or None if empty."""
    from shapely.geometry import Polygon

    shrunk = Polygon(vertices).buffer(-distance, join_style="mitre")
    if shrunk.is_empty or shrunk.area <= 0:
        return None
    return np.array(shrunk.exterior.coords)


def _draw_polygon(ax, vertices: np.ndarray, threshold_m: float | None) -> None:
    ax.add_patch(MplPolygon(vertices, closed=True, fill=True, alpha=0.15, color="tab:green", label="support polygon"))
    ax.add_patch(MplPolygon(vertices, closed=True, fill=False, color="tab:green", lw=1.5))
    if threshold_m:
        inner = shrink_polygon(vertices, threshold_m)
        if inner is not None:
            ax.add_patch(MplPolygon(inner, closed=True, fill=False, ls="--", color="tab:orange", lw=1.2,
                                    label=f"margin {threshold_m * 1000:.0f} mm"))


def _sole_outline(pose: Sequence[float], length: float, width: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(pose[3:]).as_matrix()
    hx, hy = length / 2, width / 2
    local = np.array([[hx, hy, 0], [-hx, hy, 0], [-hx, -hy, 0], [hx, -hy, 0]])
    return (local @ R.T + np.asarray(pose[:3]))[:, :2]


def plot_stance(path: Path, *, name: str, feet: list[dict], sole_sizes: dict[str, tuple[float, float]],
                polygon: np.ndarray, com: np.ndarray, margin_m: float, threshold_m: float | None = None) -> Path:
    """Feet (contact solid, raised dashed), the support polygon and the CoM ground projection."""
    fig, ax = plt.subplots(figsize=(5, 5))
    for foot in feet:
        outline = _sole_outline(foot["pose"], *sole_sizes[foot["frame"]])
        style = dict(fill=False, color="k", lw=1.0) if foot["in_contact"] else dict(fill=False, color="grey", ls=":", lw=1.0)
        ax.add_patch(MplPolygon(outline, closed=True, **style))
        label = foot["frame"] + ("" if foot["in_contact"] else f" (raised {foot['pose'][2] * 1000:.0f} mm)")
        ax.annotate(label, outline.mean(axis=0), ha="center", fontsize=8)
    _draw_polygon(ax, polygon, threshold_m)
    ax.plot(com[0], com[1], "o", color="tab:red", label=f"CoM ({margin_m * 1000:.1f} mm margin)")
    ax.set_aspect("equal")
    ax.set_xlim(-0.4, 0.3)
    ax.set_ylim(-0.3, 0.3)
    ax.set_xlabel("x (m, forward)")
    ax.set_ylabel("y (m, left)")
    return _save(fig, ax, path, f"stance: {name}")


def plot_com_trace(path: Path, *, title: str, polygon: np.ndarray, threshold_m: float,
                   traces: list[tuple[str, np.ndarray, str]]) -> Path:
    """CoM ground traces (label, (N, 2) xy, colour) over the support polygon, like the paper's Figs. 2-5."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    _draw_polygon(ax, polygon, threshold_m)
    for label, xy, colour in traces:
        xy = np.asarray(xy)
        if len(xy):
            ax.plot(xy[:, 0], xy[:, 1], "-", color=colour, lw=1.4, label=label)
            ax.plot(xy[0, 0], xy[0, 1], "o", color=colour, ms=4)
            ax.plot(xy[-1, 0], xy[-1, 1], "s", color=colour, ms=4)
    pad = 0.05
    lo, hi = polygon.min(axis=0) - pad, polygon.max(axis=0) + pad
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, forward)")
    ax.set_ylabel("y (m, left)")
    return _save(fig, ax, path, title)


def plot_margin_over_time(path: Path, *, title: str, threshold_m: float,
                          traces: list[tuple[str, np.ndarray, np.ndarray, str]]) -> Path:
    """Margin (mm) over time (s) for each trace (label, t, margin_m, colour)."""
    fig, ax = plt.subplots(figsize=(6, 3))
    for label, t, m, colour in traces:
        ax.plot(t, np.asarray(m) * 1000, color=colour, label=label)
    ax.axhline(threshold_m * 1000, color="tab:orange", ls="--", label="threshold")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("margin (mm)")
    return _save(fig, ax, path, title)


def plot_survey_bars(path: Path, *, title: str, rows: list[dict]) -> Path:
    """Bar chart of the stability ratio R per hand configuration."""
    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    names = [r["hands"] for r in rows]
    values = [r["ratio"] if r["ratio"] is not None else 0.0 for r in rows]
    bars = ax.bar(names, values, color=["tab:blue" if r["ratio"] is not None else "lightgrey" for r in rows])
    for bar, r in zip(bars, rows):
        text = f"{r['ratio']:.3f}" if r["ratio"] is not None else "n/a"
        ax.text(bar.get_x() + bar.get_width() / 2, bar.get_height() + 0.01, text, ha="center", fontsize=8)
    ax.set_ylim(0, 1.1)
    ax.set_ylabel("R = C / (C + U)")
    return _save(fig, ax, path, title, legend=False, grid=False)


def plot_survey_scatter(path: Path, *, title: str, polygon: np.ndarray, threshold_m: float,
                        xy: np.ndarray, stable: np.ndarray, max_points: int = 20000) -> Path:
    """CoM ground projections of explored states, stable green / unstable red, over the polygon."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    _draw_polygon(ax, polygon, threshold_m)
    xy = np.asarray(xy)
    stable = np.asarray(stable, dtype=bool)
    if len(xy) > max_points:
        idx = np.linspace(0, len(xy) - 1, max_points).astype(int)
        xy, stable = xy[idx], stable[idx]
    ax.scatter(xy[stable, 0], xy[stable, 1], s=2, c="tab:green", label="stable", alpha=0.5)
    ax.scatter(xy[~stable, 0], xy[~stable, 1], s=2, c="tab:red", label="unstable", alpha=0.5)
    ax.set_aspect("equal")
    return _save(fig, ax, path, title)
