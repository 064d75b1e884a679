"""The nearest posture that keeps the hands in place and the CoM margin (planner/motion/stable_posture.py).

The crouched task holds 15 kg 0.48 m in front of the soles: the IK's posture at most of its grasps
puts the system CoM closer to the toes than the 60 mm threshold. The stable posture must keep the
hand exactly where it was, stay in the joint limits, leave the legs alone, and bring the margin,
recomputed by the project's evaluator, to the threshold; with it the crouched task plans in every
hand configuration, and the independent checker agrees with the plan.
"""

from __future__ import annotations

import numpy as np
import pytest
from plan_checker import check_plan

from planner.jobs.plan_job import PlanOptions, plan_scenario
from planner.regrasp.settings import PlannerSettings
from planner.regrasp.search_data import SearchData, solve_ik, stable_posture
from planner.regrasp.task import Task
from planner.scene.scenarios import resolve_scenario
from planner.stability.evaluator import HoldSpec
from planner.transforms import inverse


@pytest.fixture(scope="module")
def crouched_task():
    return Task(resolve_scenario("crouched"), PlannerSettings(limits=False))


def _unstable_grasps(task: Task, side: str, placement: int, want: int = 6):
    """IK postures at ``side``'s grasps of one placement whose held object fails the planning threshold."""
    out = []
    T_obj = task.placements[placement]
    for k, g in enumerate(task.grasps[side]):
        q = solve_ik(task, SearchData(task), side, T_obj @ g.T_obj_tcp, task.home, np.random.default_rng(k))
        if q is None:
            continue
        q[task.jaw[side]] = g.jaw_value
        hold = HoldSpec(side, inverse(T_obj) @ task.tcp(q, side))
        if not task.evaluator.evaluate_one(q, hold).stable:
            out.append((q, hold, T_obj))
        if len(out) == want:
            break
    return out


def test_the_stable_posture_keeps_the_hand_the_limits_and_the_legs_and_reaches_the_margin(crouched_task):
    t = crouched_task
    cases = _unstable_grasps(t, "right", t.start_id) + _unstable_grasps(t, "left", t.goal_id)
    assert len(cases) >= 8, "the crouched task's IK postures should fail the margin at most grasps"
    found = 0
    for q, hold, T_obj in cases:
        side = hold.tcp_side
        before = t.evaluator.evaluate_one(q, hold).margin
        q2 = stable_posture(t, SearchData(t), q, (side,), T_obj)
        if q2 is None:
            continue
        found += 1
        after = t.evaluator.evaluate_one(q2, hold)
        assert after.stable and after.margin > before
        assert after.margin >= t.evaluator.threshold_m + t.settings.stable_posture_slack_m - 1e-6
        assert np.allclose(t.tcp(q2, side), t.tcp(q, side), atol=1e-4)  # the hand has not moved
        assert np.all(q2 >= t.robot.lower - 1e-12) and np.all(q2 <= t.robot.upper + 1e-12)
        moved = np.flatnonzero(np.abs(q2 - q) > 1e-12)
        assert set(moved) <= set(t.active[side].tolist())  # only the waist and that arm
        assert np.array_equal(q2[t.stance.leg_indices], q[t.stance.leg_indices])
        assert np.any(q2[t.robot.waist_indices()] != q[t.robot.waist_indices()])  # the waist takes part
    assert found >= len(cases) // 2, f"a stable posture for only {found} of {len(cases)} grasps"


def test_no_stable_posture_when_the_threshold_is_beyond_the_polygon(crouched_task):
    """A margin no point of the polygon has (beyond its inradius) is refused, not approximated."""
    from planner.motion.stable_posture import PostureProblem, stable_posture

    t = crouched_task
    q, hold, T_obj = _unstable_grasps(t, "right", t.start_id, want=1)[0]
    problem = PostureProblem(t.robot, t.stance.base_pose, t.stance.polygon, t.obj.mass_kg,
                             T_obj[:3, :3] @ t.obj.com_local + T_obj[:3, 3])
    tcp = t.robot.spec.arms["right"].tcp
    assert stable_posture(problem, q, t.active["right"], {tcp: t.tcp(q, "right")}, t.stance.polygon.inradius + 0.01) is None


def test_stable_postures_off_removes_the_node_as_before(crouched_task):
    t = Task(resolve_scenario("crouched"), PlannerSettings(limits=False, stable_postures=False))
    q, hold, T_obj = _unstable_grasps(t, "right", t.start_id, want=1)[0]
    assert stable_posture(t, SearchData(t), q, ("right",), T_obj) is None


@pytest.mark.parametrize("hands", ["left-left", "right-left"])
def test_the_crouched_task_plans_with_15_kg_and_the_checker_agrees(hands):
    """Without stable postures every crouched grasp at the table failed the margin; with them a single-arm and
    a handover configuration plan, keeping the threshold at every sample (recomputed independently)."""
    sc = resolve_scenario("crouched")
    plan = plan_scenario(sc, PlanOptions(hands=hands, limits=False))
    assert plan["status"] == "solved", plan.get("failure")
    assert plan["object"]["mass_kg"] == 15.0
    rep = check_plan(plan, sample_every=4)
    assert rep.errors == [] and rep.min_margin >= sc.threshold_m - 1e-4
    off = plan_scenario(sc, PlanOptions(hands=hands, limits=False), settings=PlannerSettings(limits=False, stable_postures=False))
    assert off["status"] != "solved"
