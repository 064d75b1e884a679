"""Pictures: stances, CoM traces over the support polygon, margins over time, survey charts.

Matplotlib with the Agg backend (no display needed). Every function writes one figure and
returns its path; the format follows the path's suffix (``.png``, ``.svg`` or ``.pdf``, see
:data:`FORMATS`). Every axis says what it shows and in which unit; titles say what was run
(:func:`describe`: scenario, stance, threshold, states).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Polygon as MplPolygon  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402
from shapely.geometry import Polygon  # noqa: E402

#: The figure formats the commands write (``--format``).
FORMATS = ("png", "svg", "pdf")
#: Raster resolution of PNG figures (a 6.4 x 5 in figure is 960 x 750 px).
PNG_DPI = 150
#: One colour per hand configuration, the same in every chart.
HANDS_COLOURS = {"left-left": "tab:blue", "right-right": "tab:orange", "left-right": "tab:green", "right-left": "tab:purple"}


def with_format(path: Path | str, fmt: str | None) -> Path:
    """``path`` with the suffix of ``fmt`` (png, svg, pdf); unchanged when ``fmt`` is None."""
    path = Path(path)
    if fmt is None:
        return path
    if fmt not in FORMATS:
        raise ValueError(f"unknown figure format {fmt!r}; use one of {', '.join(FORMATS)}")
    return path.with_suffix("." + fmt)


def describe(scenario: str | None = None, stance: str | None = None, threshold_m: float | None = None,
             states: int | None = None, hands: str | None = None) -> str:
    """The facts a title names: scenario, stance, threshold (mm), states, hands (those given)."""
    parts = []
    if scenario:
        parts.append(f"scenario {scenario}")
    if stance:
        parts.append(f"{stance} stance")
    if threshold_m is not None:
        parts.append(f"threshold {threshold_m * 1000:g} mm")
    if states is not None:
        parts.append(f"{states:,} states")
    if hands:
        parts.append(f"hands {hands}")
    return ", ".join(parts)


def _save(fig, ax, path: Path, title: str, *, legend: bool = True, grid: bool = True) -> Path:
    """Title, legend, grid, layout, write the figure (format from the suffix) and free it."""
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    if fmt not in FORMATS:
        plt.close(fig)
        raise ValueError(f"cannot write {path}: figures are {', '.join(FORMATS)}")
    ax.set_title(title, fontsize=10)
    if legend:
        ax.legend(loc="best", fontsize=7)
    if grid:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=PNG_DPI, format=fmt)
    plt.close(fig)
    return path


def shrink_polygon(vertices: np.ndarray, distance: float) -> np.ndarray | None:
    """The polygon shrunk inward by ``distance`` (the region where margin >= distance), or None if empty."""
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
    return _save(fig, ax, path, f"stance {name}: feet, support polygon and CoM")


def plot_com_trace(path: Path, *, title: str, polygon: np.ndarray, threshold_m: float,
                   traces: list[tuple[str, np.ndarray, str]]) -> Path:
    """CoM ground traces (label, (N, 2) xy, colour) over the support polygon, like the paper's Figs. 2-5."""
    fig, ax = plt.subplots(figsize=(7.5, 5))
    _draw_polygon(ax, polygon, threshold_m)
    marked = False
    for label, xy, colour in traces:
        xy = np.asarray(xy)
        if len(xy):
            ax.plot(xy[:, 0], xy[:, 1], "-", color=colour, lw=1.4, label=label)
            ax.plot(xy[0, 0], xy[0, 1], "o", color=colour, ms=4, label=None if marked else "start (circle)")
            ax.plot(xy[-1, 0], xy[-1, 1], "s", color=colour, ms=4, label=None if marked else "end (square)")
            marked = True
    pad = 0.05
    lo, hi = polygon.min(axis=0) - pad, polygon.max(axis=0) + pad
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, forward)")
    ax.set_ylabel("y (m, left)")
    # The legend beside the axes, never over the curves.
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7, borderaxespad=0.0)
    return _save(fig, ax, path, title, legend=False)


def holding_events(trajectory: Sequence[dict]) -> list[tuple[float, str]]:
    """Where the held object changes: (t, "pick" | "place" | "regrasp") from a plan's trajectory."""
    events = []
    for a, b in zip(trajectory, trajectory[1:]):
        ha, hb = a.get("holding", "none"), b.get("holding", "none")
        if ha != hb:
            events.append((float(b["t"]), "pick" if ha == "none" else "place" if hb == "none" else "regrasp"))
    return events


EVENT_STYLE = {"pick": ("tab:green", "-."), "place": ("tab:red", "-."), "regrasp": ("tab:brown", ":")}


def plot_margin_over_time(path: Path, *, title: str, threshold_m: float,
                          traces: list[tuple[str, np.ndarray, np.ndarray, str]],
                          events: Sequence[tuple[float, str]] = ()) -> Path:
    """CoM margin (mm) over time (s) for each trace (label, t, margin_m, colour).

    ``events`` (t, kind) mark the pick, place and regrasp moments: the margin jumps there as the
    object's mass joins or leaves the CoM (see :func:`holding_events`).
    """
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    for label, t, m, colour in traces:
        ax.plot(t, np.asarray(m) * 1000, color=colour, label=label)
    ax.axhline(threshold_m * 1000, color="tab:orange", ls="--", label=f"threshold {threshold_m * 1000:g} mm")
    seen: set[str] = set()
    for t, kind in events:
        colour, style = EVENT_STYLE.get(kind, ("grey", ":"))
        ax.axvline(t, color=colour, ls=style, lw=1, label=kind if kind not in seen else None)
        ax.annotate(kind, (t, 1.0), xycoords=("data", "axes fraction"), xytext=(2, -10), textcoords="offset points",
                    fontsize=7, color=colour)
        seen.add(kind)
    for label, t, m, colour in traces[:1]:
        if len(m):
            k = int(np.argmin(m))
            ax.plot(t[k], m[k] * 1000, "o", mfc="none", mec="tab:red", ms=8, label=f"worst {m[k] * 1000:.1f} mm at {t[k]:.2f} s")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("CoM margin to the polygon edge (mm)")
    return _save(fig, ax, path, title)


def plot_survey_bars(path: Path, *, title: str, rows: list[dict], recommended: str | None = None,
                     indistinguishable: Sequence[str] = ()) -> Path:
    """Bar chart of the stability ratio R per hand configuration, the recommended one marked.

    A row's 95 % interval (``ratio_ci95``) is drawn as an error bar where the survey has one;
    configurations whose interval overlaps the recommended one's are hatched (a tie).
    """
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    names = [r["hands"] for r in rows]
    values = [r["ratio"] if r["ratio"] is not None else 0.0 for r in rows]
    colours = [HANDS_COLOURS.get(r["hands"], "tab:blue") if r["ratio"] is not None else "lightgrey" for r in rows]
    bars = ax.bar(names, values, color=colours, edgecolor=["black" if r["hands"] == recommended else "none" for r in rows],
                  linewidth=[2.5 if r["hands"] == recommended else 0 for r in rows],
                  hatch=["//" if r["hands"] in indistinguishable else "" for r in rows])
    for bar, r in zip(bars, rows):
        ci = r.get("ratio_ci95")
        if r["ratio"] is not None and ci:
            x = bar.get_x() + bar.get_width() / 2
            ax.errorbar([x], [r["ratio"]], yerr=[[max(r["ratio"] - ci[0], 0.0)], [max(ci[1] - r["ratio"], 0.0)]], color="black", capsize=4, lw=1)
        text = f"{r['ratio']:.3f}" if r["ratio"] is not None else "n/a"
        text += f"\nC={r['stable']:,} U={r['unstable']:,}"
        if r["hands"] == recommended:
            text = "recommended\n" + text
        top = max(bar.get_height(), ci[1] if (r["ratio"] is not None and ci) else 0.0)  # above the error bar, not across it
        ax.text(bar.get_x() + bar.get_width() / 2, top + 0.03, text, ha="center", va="bottom", fontsize=7,
                fontweight="bold" if r["hands"] == recommended else "normal")
    ax.set_ylim(0, 1.3)
    ax.set_xlabel("hand configuration (start hand - end hand)")
    ax.set_ylabel("stable ratio R = C / (C + U), no unit")
    return _save(fig, ax, path, title, legend=False, grid=False)


def plot_survey_scatter(path: Path, *, title: str, polygon: np.ndarray, threshold_m: float,
                        xy: np.ndarray, stable: np.ndarray, hands: np.ndarray | None = None,
                        max_points: int = 20000) -> Path:
    """CoM ground projections of explored states over the polygon: one colour per hand configuration,
    stable states as dots, unstable ones as crosses (``hands`` None: one colour for all)."""
    fig, ax = plt.subplots(figsize=(8.4, 5.6))
    _draw_polygon(ax, polygon, threshold_m)
    xy = np.asarray(xy)
    stable = np.asarray(stable, dtype=bool)
    hands = np.asarray(hands) if hands is not None else np.full(len(xy), "all")
    if len(xy) > max_points:
        idx = np.linspace(0, len(xy) - 1, max_points).astype(int)
        xy, stable, hands = xy[idx], stable[idx], hands[idx]
    names = [h for h in HANDS_COLOURS if h in set(hands.tolist())] + sorted(set(hands.tolist()) - set(HANDS_COLOURS))
    colour_of = {name: to_rgba(HANDS_COLOURS.get(name, "tab:grey")) for name in names}
    # All configurations in one draw, in a fixed shuffled order: no configuration is painted wholly over another.
    order = np.random.default_rng(0).permutation(len(xy))
    handles = []
    for is_stable, marker, size in ((True, "o", 3), (False, "x", 14)):
        pick = order[stable[order] == is_stable]
        if len(pick):
            ax.scatter(xy[pick, 0], xy[pick, 1], s=size, marker=marker, lw=0.8,
                       c=[colour_of[h] for h in hands[pick]], alpha=0.5 if is_stable else 0.9)
    for name in names:
        sel = hands == name
        ok, bad = int((sel & stable).sum()), int((sel & ~stable).sum())
        handles.append(Line2D([], [], ls="", marker="o", ms=5, color=colour_of[name], label=f"{name}: stable ({ok:,})"))
        if bad:
            handles.append(Line2D([], [], ls="", marker="x", ms=6, color=colour_of[name], label=f"{name}: unstable ({bad:,})"))
    polygon_handles = ax.get_legend_handles_labels()[0]  # the support polygon and its threshold band
    ax.legend(handles=polygon_handles + handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7,
              borderaxespad=0.0)
    ax.set_aspect("equal")
    ax.set_xlabel("CoM x (m, forward)")
    ax.set_ylabel("CoM y (m, left)")
    return _save(fig, ax, path, title, legend=False)
