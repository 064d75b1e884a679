"""``regrasp survey --all-stances``: the per-stance tables, the stance x hands matrix and the plots.

The task is tests/data/small-box.yaml at a 70 mm threshold: the upright, staggered and crouched
stances (inradius 115-121 mm) can meet it, the one-legged stance (65 mm) cannot. ``run_survey``
is wrapped to survey one configuration per stance (key poses cost ~2 s per configuration and
stance, so this keeps the test fast) and to keep the documents it returned; the CLI's own path
does the rest. Tables with several configurations are checked in test_survey_states.py.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from planner.stability.stances import BUILTIN_STANCES
from service.cli import common as cli_common
from service.cli.main import cli
from service.cli.survey import LABELS

from .tables import table_rows

DATA = Path(__file__).parent.parent / "data"
HANDS = ["left-left"]


@pytest.fixture(scope="module")
def all_stances(tmp_path_factory):
    import planner.api.jobs
    import planner.survey.runner as survey_module

    out = tmp_path_factory.mktemp("all-stances")
    real = survey_module.run_survey
    docs = []

    def one_configuration(scenario, **kwargs):
        doc, outcomes = real(scenario, hands=HANDS, **kwargs)
        docs.append(doc)
        return doc, outcomes

    with pytest.MonkeyPatch.context() as mp:
        patched = one_configuration
        # The CLI calls it through the planner's public interface, which binds it when first imported.
        mp.setattr(survey_module, "run_survey", patched)
        mp.setattr(planner.api.jobs, "run_survey", patched)
        # The CLI's console fixed its width when it was first built, maybe by another test of this process: the
        # tables are read below, so they are drawn wide enough not to wrap.
        mp.setattr(cli_common.console, "_width", 250)
        res = CliRunner(env={"COLUMNS": "250"}).invoke(
            cli, ["survey", str(DATA / "small-box.yaml"), "--all-stances", "--threshold-mm", "70", "--states", "40",
                  "--seeds-min", "2", "--seeds-max", "2", "--workers", "1", "--plot", str(out)])
    assert res.exit_code == 0, res.output
    return res.stdout, docs, out


def test_every_stance_is_surveyed_with_the_same_task(all_stances):
    _, docs, _ = all_stances
    assert [d["stance"]["name"] for d in docs] == list(BUILTIN_STANCES)
    assert {d["threshold_m"] for d in docs} == {0.07}
    assert {d["object"]["mass_kg"] for d in docs} == {2.0}
    for d in docs:
        assert [r["hands"] for r in d["rows"]] == HANDS
        if d["stance"]["name"] == "one-legged":
            assert all(r["ratio"] is None and "inradius" in r["reason"] for r in d["rows"])
        else:
            assert all(r["stable"] + r["unstable"] == 2 * 40 and r["seeds"] == 2 for r in d["rows"]), d["rows"]


def test_each_stance_prints_a_table_of_c_u_r_with_the_recommended_marked(all_stances):
    stdout, docs, _ = all_stances
    label_of = {v: k for k, v in LABELS.items()}
    tables = stdout.split("recommended:")
    assert len(tables) == len(docs) + 1
    for text, doc in zip(tables, docs):
        assert f"{doc['stance']['name']} stance, threshold 70 mm, 40 states per seed, seeds from 1" in text
        rows = {label_of[cells[0].removesuffix(" *")]: cells for cells in table_rows(text)
                if cells[0].removesuffix(" *") in label_of}
        assert list(rows) == HANDS
        for r in doc["rows"]:
            cells = rows[r["hands"]]
            assert cells[1:3] == [str(r["stable"]), str(r["unstable"])]
            assert cells[3] == (f"{r['ratio']:.4f}" if r["ratio"] is not None else f"n/a ({r['reason']})")
            assert cells[0].endswith(" *") == (r["hands"] == doc["recommended"])
    for text, doc in zip(tables[1:], docs):
        assert text.lstrip().startswith(f"{doc['recommended']}")


def test_the_matrix_has_r_per_stance_and_hands_and_says_where_the_threshold_cannot_be_met(all_stances):
    stdout, docs, _ = all_stances
    matrix = stdout[stdout.index("R by stance and hand configuration"):]
    rows = table_rows(matrix)
    assert rows[0] == ["stance", *LABELS]
    cells = {r[0]: dict(zip(LABELS, r[1:])) for r in rows[1:]}
    assert list(cells) == list(BUILTIN_STANCES)
    for doc in docs:
        by_hands = {r["hands"]: r for r in doc["rows"]}
        for hands in LABELS:
            cell = cells[doc["stance"]["name"]][hands]
            if hands not in by_hands:
                assert cell == "not surveyed"
            elif doc["stance"]["name"] == "one-legged":
                assert cell == "threshold cannot be met"
            else:
                assert cell == f"{by_hands[hands]['ratio']:.3f}"
    # The three stances that can meet 70 mm have numbers in every surveyed cell.
    numbers = [c for s in ("upright", "staggered", "crouched") for h, c in cells[s].items() if h in HANDS]
    assert all(re.fullmatch(r"[01]\.\d{3}", c) for c in numbers), numbers


def test_plot_writes_a_bar_chart_per_stance_and_a_scatter_where_states_were_evaluated(all_stances):
    _, docs, out = all_stances
    for doc in docs:
        name = doc["stance"]["name"]
        bars, scatter = out / f"survey-{name}-bars.png", out / f"survey-{name}-scatter.png"
        assert bars.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and bars.stat().st_size > 10_000
        if name == "one-legged":
            assert not scatter.exists()  # nothing was evaluated
        else:
            assert scatter.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and scatter.stat().st_size > 10_000
            n = sum(r["stable"] + r["unstable"] for r in doc["rows"])
            assert len((out / f"survey-{name}-scatter.csv").read_text().splitlines()) == n + 1


def test_the_matrix_json_form_holds_every_stance_document(tmp_path):
    """With --json the same run is one document: {"stances": [survey, ...]} (the cheap case: a threshold no
    stance but the staggered one could meet, and there no key poses either, so nothing is explored)."""
    import json

    import planner.api.jobs
    import planner.survey.runner as survey_module

    real = survey_module.run_survey
    with pytest.MonkeyPatch.context() as mp:
        patched = lambda scenario, **kw: real(scenario, hands=["left-left"], **kw)
        # The CLI calls it through the planner's public interface, which binds it when first imported.
        mp.setattr(survey_module, "run_survey", patched)
        mp.setattr(planner.api.jobs, "run_survey", patched)
        res = CliRunner().invoke(cli, ["survey", str(DATA / "small-box.yaml"), "--all-stances", "--threshold-mm", "118",
                                       "--states", "10", "--seeds-min", "1", "--seeds-max", "1", "--workers", "1", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert [d["stance"]["name"] for d in doc["stances"]] == list(BUILTIN_STANCES)
    for d in doc["stances"]:
        (row,) = d["rows"]
        assert row["ratio"] is None and d["recommended"] is None
        assert ("inradius" in row["reason"]) == (d["stance"]["name"] != "staggered"), row
