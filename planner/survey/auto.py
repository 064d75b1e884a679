"""``hands: auto``: the order in which a plan tries the hand configurations, from the task's survey.

The survey is the task's one recommendation (docs/contract.md section 4): the scenario's default
estimator, computed once per resolved scenario and cached (:mod:`planner.survey.cache`). The plan
tries the recommended configuration first. When the recommendation is a statistical tie (other
rows' intervals overlap its own), the plan says so and tries the tied rows next in the tie order
(left-left, right-right, left-right, right-left), then the rest by ratio.
"""

from __future__ import annotations

from typing import Any, Callable

from planner.survey.cache import SurveyCache
from planner.survey.runner import run_survey
from schemas.common import HAND_CONFIGS
from schemas.survey import TIE_ORDER, recommendation_text


def auto_order(task, should_stop: Callable[[], bool]) -> tuple[list[str], dict[str, Any]]:
    """Hand configurations in the order a ``hands: auto`` plan tries them, and the survey behind it. The survey
    runs on a search scratch of its own: the plan's search must not depend on whether the survey ran or was read
    from the cache."""
    scenario = task.scenario.model_copy(update={"threshold_m": task.threshold_m, "seed": task.seed})
    doc = SurveyCache.default().get_or_run(
        scenario, lambda: run_survey(scenario, task=task, should_stop=should_stop, keep_states=False)[0],
        robot=task.robot, limits=task.limits is not None)
    return order_from(doc), doc


def order_from(doc: dict[str, Any]) -> list[str]:
    """The recommended row, its ties in the tie order, the other rows by ratio, then rows without one."""
    rows = {r["hands"]: r for r in doc["rows"]}
    best = doc.get("recommended")
    ties = [h for h in TIE_ORDER if h in (doc.get("indistinguishable") or [])]
    rated = sorted((r for r in doc["rows"] if r.get("ratio") is not None),
                   key=lambda r: (-r["ratio"], -r["stable"], TIE_ORDER.index(r["hands"])))
    order = ([best] if best else []) + ties + [r["hands"] for r in rated]
    order += [h for h in HAND_CONFIGS if h in rows or h not in order]
    seen: list[str] = []
    for h in order:
        if h not in seen:
            seen.append(h)
    return seen


def survey_summary(doc: dict[str, Any]) -> dict[str, Any]:
    """What a plan says about the survey it followed: the recommendation, and whether it is a tie."""
    ties = list(doc.get("indistinguishable") or [])
    rows = {r["hands"]: {"ratio": r.get("ratio"), "ratio_ci95": r.get("ratio_ci95"), "seeds": r.get("seeds")}
            for r in doc.get("rows") or []}
    best = doc.get("recommended")
    return {"recommended": best, "indistinguishable": ties, "tie": bool(ties),
            "ratio": (rows.get(best) or {}).get("ratio"), "ratio_ci95": (rows.get(best) or {}).get("ratio_ci95"),
            "seeds": (rows.get(best) or {}).get("seeds"), "first_seed": doc.get("seed"),
            "key_paths": (doc.get("estimator") or {}).get("key_paths"), "rows": rows,
            "task_key": (doc.get("stats") or {}).get("task_key"), "cache": (doc.get("stats") or {}).get("cache"),
            "text": recommendation_text(doc),
            "note": (f"a tie: {best} cannot be told from {', '.join(ties)} (overlapping 95 % "
                     f"intervals); tried in the tie order" if ties else None)}

