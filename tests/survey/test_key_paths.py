"""R belongs to the task, not to the seed: each row explores the planner's key paths for the key-path
seeds 1..pool (the same pool whatever the survey's base seed), and the survey's exploration is the
planner's T-RRT, biased towards the leg's start and goal (docs/contract.md section 4; docs/survey.md)."""

from __future__ import annotations

from itertools import combinations
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from planner.motion.trrt import TrrtSettings
from planner.regrasp.task import Task
from planner.scene.scenarios import load_scenario
from planner.stability.evaluator import StateBatch
from planner.survey.counting import CountingSettings, ExploreLeg, explore_counted
from planner.survey.estimator import Estimator, RowWork, run_rows
from planner.survey.runner import draw_pools, draw_seed, run_survey

#: The small box on one leg at 50 mm: its explored states straddle the threshold (real unstable states).
SCENARIO = Path(__file__).parent.parent / "data" / "one-legged-box.yaml"
BASE_SEEDS = (1, 10001, 20001)
POOL = 3


def small_estimator(seeds: int, states: int = 120, pool: int = POOL) -> Estimator:
    return Estimator(until="states", states_per_seed=states, seeds_min=seeds, seeds_max=seeds, key_path_pool=pool)


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(SCENARIO)


@pytest.fixture(scope="module")
def task(scenario):
    return Task(scenario)


@pytest.fixture(scope="module")
def surveys(scenario, task):
    """The left-left row from three base seeds whose seed ranges never meet."""
    return {s: run_survey(scenario, estimator=small_estimator(4 * POOL), seed=s, hands=["left-left"], task=task,
                          workers=1, keep_states=False)[0] for s in BASE_SEEDS}


def test_independent_base_seeds_agree_as_95_percent_intervals_should(surveys):
    rows = {s: doc["rows"][0] for s, doc in surveys.items()}
    for s, row in rows.items():
        assert row["unstable"] > 0 and row["stable"] > 0, (s, row)  # a task with real unstable states
    for a, b in combinations(BASE_SEEDS, 2):
        (lo_a, hi_a), (lo_b, hi_b) = rows[a]["ratio_ci95"], rows[b]["ratio_ci95"]
        assert lo_a <= hi_b and lo_b <= hi_a, f"seed {a}: {rows[a]['ratio_ci95']}, seed {b}: {rows[b]['ratio_ci95']}"


def test_every_base_seed_explores_the_same_pool_of_key_paths_in_equal_shares(surveys):
    pools = []
    for s, doc in surveys.items():
        assert doc["estimator"]["key_paths"] == "stratified" and doc["estimator"]["key_path_pool"] == POOL
        entries = doc["rows"][0]["per_seed"]
        assert [e["seed"] for e in entries] == list(range(s, s + 4 * POOL))
        named = [e["key_path"] for e in entries]
        assert all(k["nodes"] for k in named)
        # seed base + j explores pool member j mod pool: every key-path seed gets the same share
        assert [k["seed"] for k in named] == [1 + j % POOL for j in range(4 * POOL)]
        pools.append({k["seed"]: repr(k["nodes"]) for k in named})
    assert pools[0] == pools[1] == pools[2]


def test_a_key_path_draw_is_the_planner_s_choice_at_that_seed(scenario, task):
    """The same key-path seed gives the same key path, from any copy of the task."""
    again = draw_seed(Task(scenario), ["left-left"], 1)["left-left"]
    assert again.nodes == draw_seed(task, ["left-left"], 1)["left-left"].nodes and again.ok
    pools = draw_pools(task, ["left-left"], small_estimator(1, pool=2), workers=1, can_fork=False,
                       should_stop=lambda: False)
    assert [d.seed for d in pools["left-left"]] == [1, 2] and pools["left-left"][0].nodes == again.nodes


def test_two_very_different_key_paths_are_both_covered_by_the_row_s_interval(scenario, task):
    """A row whose pool holds two very different key paths (here: the single-arm path and the dual-arm one
    of the task) estimates their stated mix, and its interval covers it: the mix of the two paths' own
    values, each measured by independent runs of that path alone (other seeds, twice as many per path), lies
    inside the row's interval from each of two base seeds. The stratified interval thus carries both paths'
    noise; the spread between the paths is not noise of the estimate (their shares are fixed and stated)."""
    from planner.survey.runner import _leg_collisions

    evaluator = task.evaluator.with_threshold(scenario.threshold_m)
    one = [_leg_collisions(task, g) for g in draw_seed(task, ["left-left"], 1)["left-left"].legs]
    two = [_leg_collisions(task, g) for g in draw_seed(task, ["right-left"], 1)["right-left"].legs]

    def row(pool: list, base: int, seeds: int = 12) -> dict:
        r = RowWork("left-left", pool, key_paths=[{"seed": k + 1, "nodes": []} for k in range(len(pool))])
        run_rows([r], evaluator, small_estimator(seeds, states=150), base)
        v = r.verdict
        return {"C": v.stable, "N": v.stable + v.unstable, "ratio": v.stable / (v.stable + v.unstable),
                "lo": v.interval[0], "hi": v.interval[1]}

    # each key path's own value, from seeds the mixed rows never use
    a, b = row([one], base=50001, seeds=12), row([two], base=50001, seeds=12)
    assert abs(a["ratio"] - b["ratio"]) > 0.1, (a, b)  # the two key paths really differ
    mix = (a["C"] + b["C"]) / (a["N"] + b["N"])  # equal shares: the pooled ratio of equally many seeds of each
    for base in (1, 10001):
        both = row([one, two], base=base)  # 6 seeds of each path
        assert min(a["ratio"], b["ratio"]) < both["ratio"] < max(a["ratio"], b["ratio"]), (a, b, both)
        assert both["lo"] <= mix <= both["hi"], (base, mix, both)


def test_a_row_of_several_key_paths_converges_only_with_enough_seeds_of_each():
    """Identical seeds give a tight interval at once; with four distinct key paths the row still waits for
    MIN_SEEDS_PER_KEY_PATH seeds of each (the stratified interval needs each path's own noise), with one it
    stops at seeds_min."""
    from planner.survey.estimator import MIN_SEEDS_PER_KEY_PATH, SeedCount, first_converged

    est = Estimator(ci_half_width=0.05, seeds_min=4, seeds_max=64)

    def counts(pool: int, paths: int) -> list:
        return [SeedCount(seed=1 + k, stable=90, unstable=10, solved=True, status="done", time_s=0.0,
                          key_path={"seed": 1 + k % pool, "nodes": [{"grasp": k % pool % paths}]}) for k in range(64)]

    assert first_converged(counts(1, 1), est, 1, "left-left").seeds == 4
    assert first_converged(counts(4, 4), est, 1, "left-left").seeds == 4 * MIN_SEEDS_PER_KEY_PATH
    # four pool members, two distinct key paths: MIN_SEEDS_PER_KEY_PATH seeds of each path
    assert first_converged(counts(4, 2), est, 1, "left-left").seeds == 2 * MIN_SEEDS_PER_KEY_PATH
    # the planner chose one key path for the whole pool: nothing to stratify, seeds_min rules
    assert first_converged(counts(4, 1), est, 1, "left-left").seeds == 4
    # no unstable pose at all: the rule of three's interval needs no per-path noise
    sure = [SeedCount(seed=1 + k, stable=100, unstable=0, solved=True, status="done", time_s=0.0,
                      key_path={"seed": 1 + k % 4, "nodes": []}) for k in range(64)]
    assert first_converged(sure, est, 1, "left-left").seeds == 4


# -- the exploration: the planner's T-RRT --------------------------------------------------------

class _Landscape:
    """A cost landscape where the transition test matters: two active joints, every pose stable, the margin
    falling with the distance of the first joint from 0 (cost = -margin rises off the ridge)."""

    def __init__(self) -> None:
        self.robot = SimpleNamespace(nq=2, lower=np.array([-3.0, -3.0]), upper=np.array([3.0, 3.0]))

    def evaluate(self, Q, hold=None, active=None) -> StateBatch:
        Q = np.asarray(Q, float)
        margin = 0.2 - 0.2 * np.abs(Q[:, 0]) / 3.0
        n = len(Q)
        return StateBatch(np.zeros((n, 3)), np.zeros((n, 3)), margin, np.ones(n, bool), None)


def _mean_margin(margin_cost: bool, seeds: range) -> float:
    ev = _Landscape()
    leg = ExploreLeg(np.array([0.0, -2.5]), np.array([0.0, 2.5]), None, np.array([0, 1]))
    margins = []
    for seed in seeds:
        ex = explore_counted([leg], ev, np.random.default_rng(seed), budget=600,
                             settings=CountingSettings(sampler="box", bidirectional=False),
                             trrt=TrrtSettings(margin_cost=margin_cost))
        margins.append(ex.margin.mean())
    return float(np.mean(margins))


def test_the_transition_test_prefers_high_margin_samples():
    """The survey's exploration with the T-RRT transition test (margin cost) samples poses of a clearly higher
    mean margin than the same exploration, same seeds, without it (a flat cost accepts every move)."""
    with_test = _mean_margin(True, range(1, 9))
    without = _mean_margin(False, range(1, 9))
    print(f"mean margin with the transition test {with_test * 1000:.1f} mm, without {without * 1000:.1f} mm")
    assert with_test > without + 0.01, (with_test, without)


def test_the_ends_sampler_draws_near_the_leg_s_start_and_goal():
    """The samples that do not aim at the other tree: a share ends_share within +-ends_spread_rad of the leg's
    start or goal (each about half of those), the rest uniform, with the ends sampler; all over the joint box
    with the box sampler."""
    from planner.survey.counting import _Leg

    leg = ExploreLeg(np.array([0.0, -2.5]), np.array([0.0, 2.5]), None, np.array([0, 1]))
    ends = _Leg(0, leg, _Landscape(), TrrtSettings(), CountingSettings(sampler="ends", ends_share=1.0,
                                                                        ends_spread_rad=0.3))
    mixed = _Leg(0, leg, _Landscape(), TrrtSettings(), CountingSettings(sampler="ends", ends_share=0.5))
    box = _Leg(0, leg, _Landscape(), TrrtSettings(), CountingSettings(sampler="box"))
    rng = np.random.default_rng(5)
    X = np.array([ends._sample(rng) for _ in range(2000)])
    to_start, to_goal = np.abs(X - leg.start).max(axis=1), np.abs(X - leg.goal).max(axis=1)
    assert (np.minimum(to_start, to_goal) <= 0.3 + 1e-12).all()
    assert 0.4 < (to_start <= 0.3).mean() < 0.6
    M = np.array([mixed._sample(rng) for _ in range(4000)])
    near = np.minimum(np.abs(M - leg.start).max(axis=1), np.abs(M - leg.goal).max(axis=1)) <= 0.3
    assert 0.5 < near.mean() < 0.6  # half near an end, and a few of the uniform ones fall there too
    Y = np.array([box._sample(rng) for _ in range(2000)])
    assert np.minimum(np.abs(Y - leg.start).max(axis=1), np.abs(Y - leg.goal).max(axis=1)).max() > 2.0
