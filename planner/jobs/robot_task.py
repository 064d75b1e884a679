"""The task a job runs with the robot it names: the one place where a built-in task is fitted to another robot.

``regrasp plan --robot``, ``regrasp survey --robot`` and the service's plan and survey jobs (whose request's
``robot`` goes into the scenario) all go through :func:`scenario_for_robot`, so a built-in scenario run with
another registered robot is the same fitted task (:mod:`planner.scene.task_fitting`, recorded in the plan's
``scenario.fitted``) whichever way it was asked for.
"""

from __future__ import annotations

from planner.scene.task_fitting import fit_to_robot
from schemas.scenario import Scenario


def scenario_for_robot(scenario: Scenario, robot: str | None = None) -> Scenario:
    """``scenario`` run by ``robot`` (a registered name or a spec file; None keeps the scenario's own): a built-in
    scenario's task run with a robot other than its own is fitted to that robot; anything else is unchanged."""
    if robot is not None and robot != scenario.robot:
        scenario = scenario.model_copy(update={"robot": robot})
    return fit_to_robot(scenario, scenario.robot)
