"""The stability survey (``schema: regrasp.survey/1``, CONTRACT.md section 4)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from .common import HandConfig, OpenModel
from .plan import RobotRef
from .stance import StanceResult

SURVEY_SCHEMA = "regrasp.survey/1"


class SurveyRow(OpenModel):
    hands: HandConfig
    stable: int = Field(ge=0)
    unstable: int = Field(ge=0)
    ratio: float | None
    reason: str | None = None
    #: counted poses over an effort or grip limit (counted unstable too); None with the limits off
    over_limits: int | None = None


class Survey(OpenModel):
    schema_: Literal["regrasp.survey/1"] = Field(SURVEY_SCHEMA, alias="schema")
    robot: RobotRef
    stance: StanceResult
    threshold_m: float
    seed: int
    object: dict[str, Any]
    rows: list[SurveyRow]
    recommended: HandConfig | None
    stats: dict[str, Any] = Field(default_factory=dict)


TIE_ORDER: tuple[HandConfig, ...] = ("left-left", "right-right", "left-right", "right-left")


def recommend(rows: list[SurveyRow]) -> HandConfig | None:
    """Highest ratio; ties go to the larger C, then to the contract's hand order."""
    ranked = [r for r in rows if r.ratio is not None]
    if not ranked:
        return None
    best = max(ranked, key=lambda r: (r.ratio, r.stable, -TIE_ORDER.index(r.hands)))
    return best.hands
