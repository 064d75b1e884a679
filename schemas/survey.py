"""The stability survey (``schema: regrasp.survey/2``, docs/contract.md section 4).

Version 2 adds the estimator (seeds until every row's 95 % interval is tight) and, per row, the
interval, the seeds and their counts; the fields of version 1 keep their meaning."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from .common import HandConfig, OpenModel
from .plan import RobotRef
from .stance import StanceResult

SURVEY_SCHEMA = "regrasp.survey/2"


class SurveyRow(OpenModel):
    hands: HandConfig
    stable: int = Field(ge=0)
    unstable: int = Field(ge=0)
    ratio: float | None
    reason: str | None = None
    ratio_ci95: list[float] | None = Field(None, description="95 % bootstrap interval of ratio over seeds")
    seeds: int = Field(0, ge=0, description="seeds whose counts are summed")
    converged: bool = False
    per_seed: list[dict[str, Any]] = Field(default_factory=list, description="{seed, stable, unstable, solved} per seed")
    #: counted poses over an effort or grip limit (counted unstable too); None with the limits off
    over_limits: int | None = None


class Survey(OpenModel):
    schema_: Literal["regrasp.survey/2"] = Field(SURVEY_SCHEMA, alias="schema")
    robot: RobotRef
    stance: StanceResult
    threshold_m: float
    seed: int
    object: dict[str, Any]
    rows: list[SurveyRow]
    estimator: dict[str, Any] = Field(default_factory=dict)
    recommended: HandConfig | None
    indistinguishable: list[HandConfig] = Field(default_factory=list)
    stats: dict[str, Any] = Field(default_factory=dict)


TIE_ORDER: tuple[HandConfig, ...] = ("left-left", "right-right", "left-right", "right-left")


def recommend(rows: list[SurveyRow]) -> HandConfig | None:
    """Highest ratio; ties go to the larger C, then to the contract's hand order."""
    ranked = [r for r in rows if r.ratio is not None]
    if not ranked:
        return None
    best = max(ranked, key=lambda r: (r.ratio, r.stable, -TIE_ORDER.index(r.hands)))
    return best.hands


def overlaps(a: list[float] | None, b: list[float] | None) -> bool:
    """Whether two closed intervals share a point (a missing interval overlaps everything)."""
    if a is None or b is None:
        return True
    return a[0] <= b[1] and b[0] <= a[1]


def indistinguishable(rows: list[SurveyRow], best: HandConfig | None) -> list[HandConfig]:
    """The rows (other than ``best``) whose interval overlaps the recommended row's, in the tie order."""
    if best is None:
        return []
    top = next(r for r in rows if r.hands == best)
    out = [r.hands for r in rows if r.hands != best and r.ratio is not None and overlaps(r.ratio_ci95, top.ratio_ci95)]
    return sorted(out, key=TIE_ORDER.index)


def recommendation_text(doc: dict[str, Any]) -> str:
    """One line for a person: the recommended configuration with its R, 95 % interval and seeds, and its ties."""
    best = doc.get("recommended")
    if best is None:
        return "no hand configuration has a ratio"
    row = next((r for r in doc.get("rows") or [] if r["hands"] == best), {})
    ci = row.get("ratio_ci95")
    text = (f"{best}: R = {row.get('ratio'):.3f}" + (f" [{ci[0]:.3f}, {ci[1]:.3f}]" if ci else "")
            + f" over {row.get('seeds')} seeds")
    ties = list(doc.get("indistinguishable") or [])
    if ties:
        text += "; a tie with " + ", ".join(
            f"{r['hands']} {r['ratio']:.3f}" + (f" [{r['ratio_ci95'][0]:.3f}, {r['ratio_ci95'][1]:.3f}]" if r.get("ratio_ci95") else "")
            for r in doc.get("rows") or [] if r["hands"] in ties)
    return text
