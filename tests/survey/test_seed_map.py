"""The survey's seed map seam: wherever the seeds run, the survey is the same.

A seed map that ships the per-seed function to its workers as bytes (as a Ray cluster does) must
get the same document as the survey run in this process, seed for seed.
"""

from __future__ import annotations

import pickle
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import pytest

from planner.scene.scenarios import load_scenario
from planner.survey.estimator import Estimator
from planner.survey.runner import run_survey

DATA = Path(__file__).parent.parent / "data"
HANDS = ["right-right", "left-left"]


class ShippedSeeds:
    """A seed map whose workers get the per-seed function as pickled bytes, and record what they ran."""

    def __init__(self, slots: int) -> None:
        self.slots = slots
        self.ran: list[tuple[str, int]] = []
        self.canceled = 0

    def open(self, fn):
        blob = pickle.dumps(fn)
        pool = ThreadPoolExecutor(self.slots)
        outer = self

        class Session:
            def submit(self, hands: str, seed: int, keep: bool) -> Future:
                outer.ran.append((hands, seed))
                return pool.submit(lambda: pickle.loads(blob)(hands, seed, keep))

            def cancel(self, future: Future) -> None:
                outer.canceled += bool(future.cancel())

            def close(self, cancel: bool) -> None:
                pool.shutdown(wait=True, cancel_futures=cancel)

        return Session()


def test_shipped_seeds_give_the_same_survey_as_one_process():
    scenario = load_scenario(DATA / "small-box.yaml")
    est = Estimator(until="states", states_per_seed=120, seeds_min=3, seeds_max=3)
    local, _ = run_survey(scenario, estimator=est, hands=HANDS, workers=1, keep_states=False)
    shipped_map = ShippedSeeds(slots=2)
    shipped, _ = run_survey(scenario, estimator=est, hands=HANDS, keep_states=False, seed_map=shipped_map)
    assert sorted(shipped_map.ran) == sorted((h, s) for h in HANDS for s in (1, 2, 3))
    for a, b in zip(local["rows"], shipped["rows"]):
        assert a["per_seed"] == b["per_seed"] and a["ratio"] == b["ratio"] and a["ratio_ci95"] == b["ratio_ci95"]
    assert any(r["unstable"] or r["stable"] for r in local["rows"])


def test_a_cancel_stops_forked_seeds_and_leaves_no_worker():
    import multiprocessing as mp
    import time

    from planner.errors import Canceled

    scenario = load_scenario(DATA / "small-box.yaml")
    est = Estimator(until="states", states_per_seed=50_000, seeds_min=50, seeds_max=50)
    t0 = time.monotonic()
    seen: list[str] = []

    def stop() -> bool:
        return bool(seen) and time.monotonic() - t0 > 0.5

    with pytest.raises(Canceled):
        run_survey(scenario, estimator=est, hands=HANDS, workers=2, keep_states=False, should_stop=stop,
                   progress=lambda f, m: seen.append(m) if "exploring" in m else None)
    assert not mp.active_children()
