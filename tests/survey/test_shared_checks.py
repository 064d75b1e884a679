"""The survey's checks of a batch from one forward-kinematics pass (planner.survey.shared_checks) count
exactly what the checks one after the other count: the same poses, stable and unstable, the same trees."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.regrasp.task import Task
from planner.scene.scenarios import load_scenario
from planner.stability.effort import EffortEvaluator, GripLimits
from planner.survey.counting import ExploreLeg, explore_counted
from planner.survey.limits import LimitedEvaluator, over_limits
from planner.survey.runner import _leg_collisions, draw_seed
from planner.survey.shared_checks import HeldCollisions, LegChecks, leg_checks

#: The small box on one leg at 50 mm: explored states straddle the threshold, some collide, some are over a limit.
SCENARIO = Path(__file__).parent.parent / "data" / "one-legged-box.yaml"


@pytest.fixture(scope="module")
def task():
    return Task(load_scenario(SCENARIO))


def _one_after_the_other(leg: ExploreLeg) -> ExploreLeg:
    """The same leg whose collision check is a plain callable: the checks run one after the other."""
    held = leg.collision_free
    return ExploreLeg(leg.start, leg.goal, leg.hold, leg.active, lambda Q: held(Q))


@pytest.mark.parametrize("hands", ["left-left", "right-left"])
def test_one_forward_pass_counts_what_the_checks_one_after_the_other_count(task, hands):
    # a weak grip (22 N a jaw), so that the limits' check, which shares the pass too, turns stable poses unstable
    weak = {side: GripLimits(friction=0.6, force_n=22.0, patch_radius_m=0.02) for side in ("left", "right")}
    limits = EffortEvaluator(task.robot, task.stance, task.obj.mass_kg, task.obj.com_local, grip=weak)
    evaluator = LimitedEvaluator(task.evaluator.with_threshold(task.threshold_m), limits)
    legs = [_leg_collisions(task, g) for g in draw_seed(task, [hands], 1)[hands].legs]
    assert all(isinstance(g.collision_free, HeldCollisions) for g in legs)
    assert all(isinstance(leg_checks(evaluator, g.collision_free, g.hold), LegChecks) for g in legs)
    plain = [_one_after_the_other(g) for g in legs]
    assert all(leg_checks(evaluator, g.collision_free, g.hold) is None for g in plain)
    for seed in (1, 2):
        shared = explore_counted(legs, evaluator, np.random.default_rng(seed), budget=400)
        apart = explore_counted(plain, evaluator, np.random.default_rng(seed), budget=400)
        assert shared.n_unstable > 0 and shared.n_stable > 0, (hands, seed)  # real unstable poses
        over = over_limits(limits, shared.q, shared.holding, shared.object_pose)
        assert 0 < over == over_limits(limits, apart.q, apart.holding, apart.object_pose), (hands, seed)
        assert ((shared.margin >= task.threshold_m) & ~shared.stable).any()  # a limit turned stable poses unstable
        assert shared.stats["rejected"]["collision"] > 0
        assert shared.stats["rejected"] == apart.stats["rejected"]
        assert [vars(a) for a in shared.legs] == [vars(b) for b in apart.legs]
        np.testing.assert_array_equal(shared.q, apart.q)
        np.testing.assert_array_equal(shared.stable, apart.stable)
        np.testing.assert_allclose(shared.margin, apart.margin, rtol=0, atol=1e-9)
        np.testing.assert_allclose(shared.object_pose, apart.object_pose, rtol=0, atol=1e-9)
