"""Planning and surveying: the workers' entry points and the CLI's runs."""

from __future__ import annotations

from planner.forking import declare_fork_benign
from planner.jobs.entry import JobContext
from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.survey.cache import SurveyCache
from planner.survey.runner import run_survey, write_states
from planner.survey.seed_map import SeedFn, SeedMap

__all__ = ["JobContext", "PlanOptions", "SeedFn", "SeedMap", "SurveyCache", "declare_fork_benign", "plan_scenario",
           "run_survey", "write_states"]
