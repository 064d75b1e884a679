"""Which configuration the survey recommends (docs/contract.md section 4), and the order --hands auto tries.

The rule: the highest ratio R; ties go to the larger C, then to the order left-left, right-right,
left-right, right-left; rows without a ratio (no plan, threshold beyond the polygon) never win.
"""

from __future__ import annotations

from fractions import Fraction

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.survey import SurveyRow, recommend

CONTRACT_ORDER = ["left-left", "right-right", "left-right", "right-left"]


def row(hands: str, stable: int, unstable: int) -> SurveyRow:
    total = stable + unstable
    return SurveyRow(hands=hands, stable=stable, unstable=unstable, ratio=stable / total if total else None,
                     reason=None if total else "no feasible grasp or key poses")


def by_the_contract(rows: list[SurveyRow]) -> list[str]:
    """The contract's ranking written out with exact fractions: best first, rows without a ratio dropped."""
    ranked = [r for r in rows if r.stable + r.unstable]
    return [r.hands for r in sorted(ranked, key=lambda r: (-Fraction(r.stable, r.stable + r.unstable), -r.stable,
                                                           CONTRACT_ORDER.index(r.hands)))]


@pytest.mark.parametrize("rows,expected", [
    # The highest R wins over a larger C and over an earlier place in the order.
    ([row("left-left", 800, 200), row("right-right", 700, 100), row("right-left", 9, 1)], "right-left"),
    ([row("left-left", 999, 1), row("left-right", 9999, 1)], "left-right"),
    # Equal R: the larger C.
    ([row("left-left", 1, 1), row("right-left", 2, 2)], "right-left"),
    ([row("left-left", 1, 2), row("right-right", 2, 4), row("left-right", 3, 6)], "left-right"),
    ([row("right-right", 300, 0), row("left-left", 299, 0)], "right-right"),
    # Equal R and C: the contract's order, whatever the order of the rows.
    ([row("right-left", 5, 5), row("left-right", 5, 5), row("right-right", 5, 5)], "right-right"),
    ([row("right-left", 3, 1), row("left-right", 3, 1)], "left-right"),
    ([row("right-left", 7, 0), row("left-right", 7, 0), row("right-right", 7, 0), row("left-left", 7, 0)], "left-left"),
    # Rows without a ratio never win, even listed first or in the contract's first place.
    ([row("left-left", 0, 0), row("right-right", 1, 9)], "right-right"),
    ([row("left-left", 0, 0), row("right-right", 0, 0)], None),
    ([], None),
])
def test_recommend_follows_the_contract(rows, expected):
    assert recommend(rows) == expected
    assert by_the_contract(rows)[:1] == ([expected] if expected else [])


counts = st.integers(0, 12)


@given(st.permutations(CONTRACT_ORDER).flatmap(
    lambda order: st.tuples(st.just(order), st.integers(0, 4), st.lists(st.tuples(counts, counts), min_size=4, max_size=4))))
def test_recommend_agrees_with_the_rule_for_any_counts(drawn):
    """Small counts make equal ratios (1/2 = 3/6) and equal C common; any subset, any row order."""
    order, n, pairs = drawn
    rows = [row(h, c, u) for h, (c, u) in zip(order[:n], pairs)]
    ranked = by_the_contract(rows)
    assert recommend(rows) == (ranked[0] if ranked else None)


def test_hands_auto_tries_the_configurations_in_the_survey_s_order(monkeypatch):
    """--hands auto ranks the quick survey's rows: the recommended first, then by the same rule, then the
    configurations without a ratio in the contract's order."""
    import planner.jobs.plan_job as jobs

    rows = [row("left-left", 6, 2), row("right-right", 0, 0), row("left-right", 3, 1), row("right-left", 9, 1)]
    doc = {"rows": [r.model_dump() for r in rows], "recommended": recommend(rows)}
    monkeypatch.setattr(jobs, "quick_survey", lambda task, should_stop=None: doc)
    order, survey_doc = jobs._auto_order(None, lambda: False)
    assert survey_doc is doc
    assert order[0] == doc["recommended"] == "right-left"
    # left-left and left-right both have R = 0.75: the larger C (6) first.
    assert order == ["right-left", "left-left", "left-right", "right-right"]


@given(st.permutations(CONTRACT_ORDER), st.lists(st.tuples(counts, counts), min_size=4, max_size=4))
def test_hands_auto_order_agrees_with_the_rule_for_any_counts(order, pairs):
    import planner.jobs.plan_job as jobs

    rows = [row(h, c, u) for h, (c, u) in zip(order, pairs)]
    doc = {"rows": [r.model_dump() for r in rows], "recommended": recommend(rows)}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(jobs, "quick_survey", lambda task, should_stop=None: doc)
        tried, _ = jobs._auto_order(None, lambda: False)
    ranked = by_the_contract(rows)
    assert tried == ranked + [h for h in CONTRACT_ORDER if h not in ranked]
    assert tried[0] == (doc["recommended"] or "left-left")


@given(st.permutations(CONTRACT_ORDER), st.lists(st.one_of(st.none(), st.integers(0, 4)), min_size=4, max_size=4))
def test_a_survey_for_the_recommendation_only_recommends_what_the_whole_survey_does(order, stable):
    """`hands: auto` skips the configurations a surveyed one outranks whatever they would count
    (planner.survey.runner._outranked), in the one-process order of any request: the recommendation is unchanged. Four
    states per configuration make R = 1 and ties common; None is a configuration without key poses."""
    from planner.survey.runner import ConfigOutcome, _outranked, _serial_order

    n = 4
    whole = [ConfigOutcome(h, 0, 0, "no feasible grasp or key poses", {}) if c is None else ConfigOutcome(h, c, n - c, None, {})
             for h, c in zip(order, stable)]
    done: list[ConfigOutcome] = []
    for k in _serial_order(order):
        why = _outranked(order[k], done, n)
        done.append(ConfigOutcome(order[k], 0, 0, why, {}) if why else whole[k])

    def rows(outcomes):
        return [SurveyRow(hands=o.hands, stable=o.stable, unstable=o.unstable, ratio=o.ratio, reason=o.reason) for o in outcomes]

    assert recommend(rows(done)) == recommend(rows(whole))
    skipped = [o.hands for o in done if o.reason and o.reason.startswith("not surveyed")]
    assert all(CONTRACT_ORDER.index(h) > CONTRACT_ORDER.index(recommend(rows(whole))) for h in skipped)
