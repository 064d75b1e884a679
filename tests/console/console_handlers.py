"""Job handlers for the console's end-to-end test: return the fake API's plan and survey documents.

They run in the real service's worker processes, so the page draws a real job's
result without the planner's run time.
"""

from __future__ import annotations

from typing import Any

from tests.console.fake_api import synthetic_plan, synthetic_survey


def run_plan(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    ctx.progress(0.5, "drawing the plan")
    return synthetic_plan()


def run_survey(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    ctx.progress(0.5, "counting")
    return synthetic_survey()
