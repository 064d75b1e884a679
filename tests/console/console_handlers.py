"""Job handlers for the console's end-to-end test: return the fake API's plan and survey documents.

They run in the real service's worker processes, so the page draws a real job's
result without the planner's run time. The scenario ``console-slow`` keeps a plan
job planning until it is canceled (for the console's cancel button).
"""

from __future__ import annotations

import time
from typing import Any

from tests.console.fake_api import synthetic_plan, synthetic_survey

#: Scenario name that keeps a plan job planning (polling for a cancel) until canceled or this many s passed.
SLOW_SCENARIO = "console-slow"
SLOW_LIMIT_S = 60.0
CANCEL_POLL_S = 0.02


def run_plan(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    if request.get("scenario") == SLOW_SCENARIO:
        from planner.errors import Canceled

        end = time.monotonic() + SLOW_LIMIT_S
        while time.monotonic() < end:
            if ctx.cancelled():
                raise Canceled("canceled while planning")
            ctx.progress(0.1, "planning slowly")
            time.sleep(CANCEL_POLL_S)
    ctx.progress(0.5, "drawing the plan")
    return synthetic_plan()


def run_survey(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    ctx.progress(0.5, "counting")
    return synthetic_survey()
