"""``regrasp robot check --plot``: each built-in stance's soles, support polygon and CoM, seen from above.

One panel per stance that solves, world x forward (up the page) and y to the robot's left (to the left of
the page), so a sole placed behind the ankle or a CoM off the polygon's centre shows at a glance.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_footprints(name: str, footprints, path: Path) -> Path:  # type: ignore[no-untyped-def]
    """Write the figure of ``footprints`` (:class:`planner.scene.robot_report.FootPrint`) to ``path``."""
    n = max(len(footprints), 1)
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n, 4.2), squeeze=False)
    for ax, fp in zip(axes[0], footprints):
        for k, sole in enumerate(fp.soles):
            closed = np.vstack([sole, sole[:1]])
            ax.fill(-closed[:, 1], closed[:, 0], color="tab:blue", alpha=0.25, label="soles" if k == 0 else None)
        if len(fp.polygon):
            poly = np.vstack([fp.polygon, fp.polygon[:1]])
            ax.plot(-poly[:, 1], poly[:, 0], color="tab:blue", lw=1.5, label="support polygon")
            centre = fp.polygon.mean(axis=0)
            ax.plot(-centre[1], centre[0], "+", color="tab:blue", ms=10)
        ax.plot(-fp.com[1], fp.com[0], "o", color="tab:red", label=f"CoM (margin {fp.margin_m * 1000:.0f} mm)")
        ax.set_title(fp.stance)
        ax.set_aspect("equal")
        ax.set_xlabel("y (m, robot's left to the left)")
        ax.set_ylabel("x (m, forward)")
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{-v:g}"))
        ax.legend(fontsize=7, loc="lower center")
        ax.grid(alpha=0.3)
    fig.suptitle(f"{name}: feet, support polygon and CoM")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
