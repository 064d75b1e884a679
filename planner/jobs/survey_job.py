"""The service's survey job: a request in, the survey document out, its answer cached for ``hands: auto``."""

from __future__ import annotations

from typing import Any

from planner.jobs.robot_task import scenario_for_robot
from planner.scene.scenarios import resolve_scenario
from planner.survey.cache import SurveyCache
from planner.survey.runner import run_survey


def survey_overrides(request: dict[str, Any]) -> dict[str, Any] | None:
    """The survey estimator fields of a request (docs/contract.md section 5), for ``with_overrides(survey=...)``."""
    fields = {k: request.get(k) for k in ("until", "ci_half_width", "seeds_min", "seeds_max", "states_per_seed")}
    if request.get("states_per_configuration") is not None:
        fields.update(until="states", states_per_seed=request["states_per_configuration"])
    return {k: v for k, v in fields.items() if v is not None} or None



def survey_job(request: dict[str, Any], ctx: Any) -> dict[str, Any]:
    """The survey of the request (docs/contract.md section 5), computed once per resolved scenario.

    A context with a ``seed_map`` (the Ray executor's) runs the seeds there, across the cluster."""
    scenario = resolve_scenario(request["scenario"], stance=request.get("stance"), threshold_m=request.get("threshold_m"),
                                seed=request.get("seed"), time_limit_s=request.get("time_limit_s"),
                                survey=survey_overrides(request))
    # the request's robot is in the scenario (resolve_request): a built-in task is fitted to it, as a plan's is
    scenario = scenario_for_robot(scenario)
    return SurveyCache.default().get_or_run(
        scenario, lambda: run_survey(scenario, should_stop=lambda: bool(ctx.cancelled()), progress=ctx.progress,
                                     keep_states=False, seed_map=getattr(ctx, "seed_map", None))[0])
