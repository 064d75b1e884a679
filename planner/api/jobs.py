"""Planning and surveying: the workers' entry points, the CLI's and the experiments' runs, the survey's
interval and the diagnosis of its handovers."""

from __future__ import annotations

from planner.forking import declare_fork_benign
from planner.jobs.entry import JobContext
from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.jobs.robot_task import scenario_for_robot
from planner.regrasp.settings import PlannerSettings
from planner.survey.cache import SurveyCache
from planner.survey.counting import CountingSettings
from planner.survey.estimator import bootstrap_rng, ratio_interval
from planner.survey.handovers import handover_diagnosis
from planner.survey.runner import run_survey, write_states
from planner.survey.seed_map import SeedFn, SeedMap

__all__ = ["CountingSettings", "JobContext", "PlanOptions", "PlannerSettings", "SeedFn", "SeedMap", "SurveyCache",
           "bootstrap_rng", "declare_fork_benign", "handover_diagnosis", "plan_scenario", "ratio_interval", "run_survey",
           "scenario_for_robot", "write_states"]
