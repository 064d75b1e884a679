"""On one foot the ZMP keeps a share of the CoM's own margin at every point (``zmp_local_share_one_foot``), and the
physics twin's feet feel the difference: the one-hand one-legged plan (right-right, seed 1) carries the object
towards the sole's edge, where its static margin is 3 mm over the threshold. Braking there with the ZMP at the
run's floor, the stabilized body's centre of pressure overshoots the planned ZMP and comes within 0.64 of the plan's
static minimum; braking while the CoM still has room, it keeps at least the 0.75 the timing targets."""

from __future__ import annotations

from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.regrasp.settings import PlannerSettings
from planner.scene.scenarios import load_builtin
from robot_bridge.physics.simulate import simulate


def _played(local_share: float) -> tuple[dict, dict]:
    """The one-legged right-right plan (seed 1) timed with that local share, and the twin's report of it."""
    base = PlannerSettings()
    timing = base.plan_timing.model_copy(update={"zmp_local_share_one_foot": local_share})
    plan = plan_scenario(load_builtin("one-legged"), PlanOptions(hands="right-right", seed=1),
                         settings=base.model_copy(update={"plan_timing": timing}))
    assert plan["status"] == "solved"
    return plan, simulate(plan).report


def test_on_one_foot_the_twin_keeps_three_quarters_of_the_static_margin_only_with_the_local_share():
    plan, report = _played(PlannerSettings().plan_timing.zmp_local_share_one_foot)
    assert plan["timing"]["zmp_local_share"] == 0.9  # recorded in the plan
    assert report["fault"] is None
    assert report["cop_margin_ratio"] >= 0.75
    assert report["min_cop_margin_m"] >= 0.75 * plan["min_margin_m"]  # the ratio recomputed from its parts

    free_plan, free = _played(0.0)
    assert free_plan["timing"]["zmp_local_share"] == 0.0
    assert free["fault"] is None and free["cop_margin_ratio"] < 0.75  # the run's floor alone: the CoP overshoots
    assert free_plan["timing"]["duration_s"] < plan["timing"]["duration_s"]  # what the balance costs in time
