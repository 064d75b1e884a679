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
    colours = {}
    for coll in ax.collections:
        label = coll.get_label()
        if ":" in label:
            colours.setdefault(label.split(":")[0], set()).add(mcolors.to_hex(coll.get_facecolor()[0], keep_alpha=False))
    assert set(colours) == {"left-left", "right-right", "left-right", "right-left"}
    # one colour per configuration, and four different ones
    assert all(len(c) == 1 for c in colours.values()) and len({next(iter(c)) for c in colours.values()}) == 4
    assert colours["left-left"] == {mcolors.to_hex(plots.HANDS_COLOURS["left-left"])}
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
