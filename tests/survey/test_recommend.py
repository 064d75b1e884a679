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


def test_hands_auto_tries_the_configurations_in_the_survey_s_order():
    """--hands auto ranks the survey's rows: the recommended first, then by the same rule, then the
    configurations without a ratio in the contract's order."""
    from planner.survey.auto import order_from

    rows = [row("left-left", 6, 2), row("right-right", 0, 0), row("left-right", 3, 1), row("right-left", 9, 1)]
    doc = {"rows": [r.model_dump() for r in rows], "recommended": recommend(rows), "indistinguishable": []}
    order = order_from(doc)
    assert order[0] == doc["recommended"] == "right-left"
    # left-left and left-right both have R = 0.75: the larger C (6) first.
    assert order == ["right-left", "left-left", "left-right", "right-right"]


def test_on_a_tie_the_plan_says_so_and_tries_the_tied_rows_in_the_tie_order():
    """Overlapping intervals: the recommendation cannot be told from the rows it overlaps; they come next in
    the order left-left, right-right, left-right, right-left, whatever their ratios."""
    from planner.survey.auto import order_from, survey_summary
    from schemas.survey import indistinguishable

    rows = [row("left-left", 80, 20), row("right-right", 85, 15), row("left-right", 90, 10), row("right-left", 50, 50)]
    for r, ci in zip(rows, ([0.70, 0.88], [0.78, 0.92], [0.84, 0.95], [0.40, 0.60])):
        r.ratio_ci95 = ci
    best = recommend(rows)
    ties = indistinguishable(rows, best)
    assert best == "left-right" and ties == ["left-left", "right-right"]
    doc = {"rows": [r.model_dump() for r in rows], "recommended": best, "indistinguishable": ties}
    assert order_from(doc) == ["left-right", "left-left", "right-right", "right-left"]
    summary = survey_summary(doc)
    assert summary["tie"] and "a tie" in summary["note"] and summary["indistinguishable"] == ties
    assert not survey_summary({**doc, "indistinguishable": []})["tie"]


@given(st.permutations(CONTRACT_ORDER), st.lists(st.tuples(counts, counts), min_size=4, max_size=4))
def test_hands_auto_order_agrees_with_the_rule_for_any_counts(order, pairs):
    from planner.survey.auto import order_from

    rows = [row(h, c, u) for h, (c, u) in zip(order, pairs)]
    doc = {"rows": [r.model_dump() for r in rows], "recommended": recommend(rows), "indistinguishable": []}
    tried = order_from(doc)
    ranked = by_the_contract(rows)
    assert tried == ranked + [h for h in CONTRACT_ORDER if h not in ranked]
    assert tried[0] == (doc["recommended"] or "left-left")
