"""The CLI's output flags: ``--json`` on ``plan`` and ``scenario list``, ``--format`` on the figures."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from service.cli.main import cli

ROOT = Path(__file__).resolve().parent.parent
SMALL_BOX = str(ROOT / "tests" / "data" / "small-box.yaml")


def test_scenario_list_json_lists_every_builtin_with_its_own_values():
    from planner.scene.scenarios import builtin_names, load_builtin

    out = CliRunner().invoke(cli, ["scenario", "list", "--json"])
    assert out.exit_code == 0, out.output
    entries = json.loads(out.output)
    assert [e["name"] for e in entries] == builtin_names()
    for e in entries:
        sc = load_builtin(e["name"])
        assert e["threshold_m"] == sc.threshold_m and e["hands"] == sc.hands and e["seed"] == sc.seed
    assert {e["name"]: e["threshold_m"] for e in entries}["staggered"] == 0.03


def test_plan_json_prints_the_summary_and_writes_the_figures_in_the_format_asked(tmp_path):
    out_dir = tmp_path / "out"
    result = CliRunner().invoke(cli, ["plan", SMALL_BOX, "--out", str(out_dir / "plan.json"), "--plot",
                                      str(out_dir / "com"), "--format", "svg", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)  # stdout is the JSON document alone
    plan = json.loads((out_dir / "plan.json").read_text())
    assert summary["status"] == plan["status"] == "solved"
    assert summary["min_margin_m"] == plan["min_margin_m"] and summary["points"] == len(plan["trajectory"])
    assert abs(summary["headroom_m"] - (plan["min_margin_m"] - plan["threshold_m"])) < 1e-12
    assert [Path(f).name for f in summary["figures"]] == ["com.svg", "com-margin.svg"]
    margin_svg = (out_dir / "com-margin.svg").read_text()
    assert margin_svg.startswith("<?xml") and "pick" in margin_svg and "place" in margin_svg


def test_plan_format_overrides_the_plot_suffix(tmp_path):
    result = CliRunner().invoke(cli, ["plan", SMALL_BOX, "--out", str(tmp_path / "p.json"), "--plot",
                                      str(tmp_path / "com.png"), "--format", "pdf", "--quiet"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "com.pdf").read_bytes()[:4] == b"%PDF" and not (tmp_path / "com.png").exists()


def test_a_bad_format_is_refused_before_any_work():
    result = CliRunner().invoke(cli, ["plan", SMALL_BOX, "--out", "x.json", "--plot", "x", "--format", "jpg"])
    assert result.exit_code == 2 and "'jpg' is not one of 'png', 'svg', 'pdf'" in result.output
