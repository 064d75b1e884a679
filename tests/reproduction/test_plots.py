"""The figures: labelled axes with units, one colour per hand configuration, the recommended bar
marked, pick and place marked on the margin plot, and the three formats.

The figures are drawn for real and read back: the SVG text holds the labels, titles and legend
entries; the rendered axes hold the scatter's colours.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.colors as mcolors  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from experiments import plots  # noqa: E402

POLYGON = np.array([[-0.1, -0.15], [0.12, -0.15], [0.12, 0.15], [-0.1, 0.15]])
ROWS = [
    {"hands": "left-left", "stable": 980, "unstable": 20, "ratio": 0.98, "ratio_ci95": [0.97, 0.99]},
    {"hands": "right-right", "stable": 900, "unstable": 100, "ratio": 0.90, "ratio_ci95": [0.88, 0.92]},
    {"hands": "left-right", "stable": 970, "unstable": 30, "ratio": 0.97, "ratio_ci95": [0.955, 0.985]},
    {"hands": "right-left", "stable": 0, "unstable": 0, "ratio": None, "reason": "no feasible handover"},
]


def _texts(path) -> str:
    """The text of an SVG written with its fonts as text (labels, ticks, legend)."""
    return path.read_text()


@pytest.fixture(autouse=True)
def svg_text():
    with matplotlib.rc_context({"svg.fonttype": "none"}):
        yield


def test_margin_plot_labels_units_and_marks_pick_and_place(tmp_path):
    t = np.linspace(0, 10, 201)
    m = 0.05 + 0.02 * np.sin(t)
    traj = [{"t": float(x), "holding": "right" if 3 <= x < 7 else "none"} for x in t]
    events = plots.holding_events(traj)
    assert [k for _, k in events] == ["pick", "place"]
    assert events[0][0] == pytest.approx(3.0) and events[1][0] == pytest.approx(7.0)
    path = plots.plot_margin_over_time(tmp_path / "m.svg", title="CoM margin: " + plots.describe("upright", "upright", 0.06),
                                       threshold_m=0.06, traces=[("planned", t, m, "tab:blue")], events=events)
    svg = _texts(path)
    for text in ("time (s)", "CoM margin to the polygon edge (mm)", "pick", "place", "threshold 60 mm",
                 "scenario upright, upright stance, threshold 60 mm", f"worst {m.min() * 1000:.1f} mm"):
        assert text in svg, text


def test_survey_bars_mark_the_recommended_configuration(tmp_path):
    path = plots.plot_survey_bars(tmp_path / "b.svg", title=plots.describe("upright", "upright", 0.06, states=1000),
                                  rows=ROWS, recommended="left-left", indistinguishable=["left-right"])
    svg = _texts(path)
    assert svg.count("recommended") == 1
    for text in ("hand configuration", "stable ratio R = C / (C + U)", "1,000 states", "n/a", "C=980 U=20"):
        assert text in svg, text


def test_survey_bars_draw_the_recommended_bar_outlined(monkeypatch, tmp_path):
    seen = {}
    real_close = plt.close

    def keep(fig):
        seen["fig"] = fig
        real_close(fig)

    monkeypatch.setattr(plots.plt, "close", keep)
    plots.plot_survey_bars(tmp_path / "b.png", title="t", rows=ROWS, recommended="left-left")
    bars = [p for p in seen["fig"].axes[0].patches]
    widths = [b.get_linewidth() for b in bars]
    assert widths[0] > 1 and all(w == 0 for w in widths[1:])  # only the recommended bar is outlined


def test_survey_scatter_colours_each_configuration_with_a_legend(monkeypatch, tmp_path):
    rng = np.random.default_rng(3)
    hands = np.repeat(["left-left", "right-right", "left-right", "right-left"], 50)
    xy = rng.normal(0, 0.05, (200, 2))
    stable = rng.random(200) > 0.2
    seen = {}
    real_close = plt.close

    def keep(fig):
        seen["fig"] = fig
        real_close(fig)

    monkeypatch.setattr(plots.plt, "close", keep)
    path = plots.plot_survey_scatter(tmp_path / "s.svg", title="explored", polygon=POLYGON, threshold_m=0.03, xy=xy,
                                     stable=stable, hands=hands)
    ax = seen["fig"].axes[0]
    legend = ax.get_legend()
    colours = {}
    for handle, text in zip(legend.legend_handles, legend.get_texts()):
        if ":" in text.get_text():
            colours.setdefault(text.get_text().split(":")[0], set()).add(mcolors.to_hex(handle.get_color(), keep_alpha=False))
    assert set(colours) == {"left-left", "right-right", "left-right", "right-left"}
    # one colour per configuration, and four different ones
    assert all(len(c) == 1 for c in colours.values()) and len({next(iter(c)) for c in colours.values()}) == 4
    assert colours["left-left"] == {mcolors.to_hex(plots.HANDS_COLOURS["left-left"])}
    # No configuration is painted wholly over another: the points drawn last (on top) hold every configuration.
    stable_points = max(ax.collections, key=lambda c: len(c.get_offsets()))
    top = {mcolors.to_hex(c, keep_alpha=False) for c in stable_points.get_facecolors()[-40:]}
    assert top == {mcolors.to_hex(plots.HANDS_COLOURS[h]) for h in colours}
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(t.startswith("left-left: stable") for t in legend) and any("unstable" in t for t in legend)
    svg = _texts(path)
    assert "CoM x (m, forward)" in svg and "CoM y (m, left)" in svg


@pytest.mark.parametrize("fmt, magic", [("png", b"\x89PNG"), ("svg", b"<?xml"), ("pdf", b"%PDF")])
def test_every_figure_writes_each_format(tmp_path, fmt, magic):
    t = np.linspace(0, 1, 11)
    target = plots.with_format(tmp_path / "fig.png", fmt)
    assert target.suffix == "." + fmt
    path = plots.plot_margin_over_time(target, title="x", threshold_m=0.03, traces=[("m", t, t * 0.1, "k")])
    assert path.read_bytes()[: len(magic)] == magic
    path = plots.plot_com_trace(tmp_path / f"com.{fmt}", title="x", polygon=POLYGON, threshold_m=0.03,
                                traces=[("c", np.zeros((3, 2)), "k")])
    assert path.read_bytes()[: len(magic)] == magic


def test_png_figures_are_large_enough_to_publish(tmp_path):
    from PIL import Image

    path = plots.plot_survey_bars(tmp_path / "b.png", title="t", rows=ROWS, recommended="left-left")
    width, height = Image.open(path).size
    assert width >= 900 and height >= 550


def test_an_unknown_format_is_refused_with_the_valid_ones(tmp_path):
    with pytest.raises(ValueError, match="png, svg, pdf"):
        plots.with_format(tmp_path / "x.png", "jpg")
    with pytest.raises(ValueError, match="png, svg, pdf"):
        plots.plot_survey_bars(tmp_path / "x.jpg", title="t", rows=ROWS)


def _figure_of(monkeypatch, module) -> dict:
    seen: dict = {}
    real_close = module.plt.close

    def keep(fig):
        seen["fig"] = fig
        real_close(fig)

    monkeypatch.setattr(module.plt, "close", keep)
    return seen


def test_every_survey_plot_gives_a_configuration_the_same_colour(monkeypatch, tmp_path):
    """The convergence plot uses the bars' and the scatter's colours (right-right is one colour everywhere)."""
    from experiments import convergence_plot

    seen = _figure_of(monkeypatch, convergence_plot)
    per_seed = [{"seed": s, "stable": 90 + s, "unstable": 10, "solved": True} for s in range(1, 6)]
    rows = [{"hands": h, "stable": sum(p["stable"] for p in per_seed), "unstable": 50, "ratio": 0.9,
             "ratio_ci95": [0.88, 0.92], "seeds": 5, "per_seed": per_seed} for h in ("left-left", "right-right")]
    convergence_plot.plot_convergence(tmp_path / "c.png", {"seed": 1, "rows": rows, "stance": {"name": "upright"}})
    lines = {line.get_label(): mcolors.to_hex(line.get_color()) for line in seen["fig"].axes[0].get_lines()}
    for hands in ("left-left", "right-right"):
        label = next(k for k in lines if k.startswith(hands))
        assert lines[label] == mcolors.to_hex(plots.HANDS_COLOURS[hands]), (hands, lines)


def test_a_bar_label_sits_above_its_error_bar(monkeypatch, tmp_path):
    seen = _figure_of(monkeypatch, plots)
    rows = [{"hands": "left-left", "stable": 90, "unstable": 10, "ratio": 0.9, "ratio_ci95": [0.7, 0.99]},
            {"hands": "right-right", "stable": 50, "unstable": 50, "ratio": 0.5, "ratio_ci95": [0.3, 0.8]}]
    plots.plot_survey_bars(tmp_path / "b.png", title="bars", rows=rows, recommended="left-left")
    ax = seen["fig"].axes[0]
    for row in rows:
        text = next(t for t in ax.texts if f"{row['ratio']:.3f}" in t.get_text())
        assert text.get_position()[1] > row["ratio_ci95"][1], (row, text.get_position())


def test_the_com_trace_legend_names_the_markers_and_stays_off_the_curves(monkeypatch, tmp_path):
    seen = _figure_of(monkeypatch, plots)
    xy = np.column_stack([np.linspace(-0.05, 0.05, 30), np.linspace(0.0, 0.1, 30)])
    plots.plot_com_trace(tmp_path / "t.png", title="CoM", polygon=POLYGON, threshold_m=0.03,
                         traces=[("planned", xy, "tab:blue"), ("unconstrained", xy * 0.5, "tab:grey")])
    fig = seen["fig"]
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "start (circle)" in labels and "end (square)" in labels and "planned" in labels and "unconstrained" in labels
    fig.canvas.draw()
    legend_box = ax.get_legend().get_window_extent()
    axes_box = ax.get_window_extent()
    assert legend_box.x0 >= axes_box.x1 - 1  # beside the axes: it covers no curve
