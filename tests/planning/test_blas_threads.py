"""The planner's own work runs with one BLAS thread per process (planner/blas_threads.py), and gives the caller's
limit back after."""

from __future__ import annotations

import pytest
from threadpoolctl import ThreadpoolController, threadpool_info, threadpool_limits

from planner.jobs import plan_job
from planner.scene.scenarios import load_builtin
from planner.survey import runner


def _blas_threads() -> set[int]:
    return {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}


class _Seen(Exception):
    """Ends the call once the threads inside it were read."""


def test_a_plan_and_a_survey_run_with_one_blas_thread_and_restore_the_callers_limit(monkeypatch):
    seen: list[set[int]] = []

    def record(*args, **kwargs):
        seen.append(_blas_threads())
        raise _Seen

    monkeypatch.setattr(plan_job, "build_task", record)
    monkeypatch.setattr(runner, "estimator_of", record)
    scenario = load_builtin("upright")
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        for call in (lambda: plan_job.plan_scenario(scenario), lambda: runner.run_survey(scenario)):
            with pytest.raises(_Seen):
                call()
            assert _blas_threads() == before
    assert before == {2}
    assert seen == [{1}, {1}]


def test_a_remote_seed_runs_with_one_blas_thread():
    seen: list[set[int]] = []

    class Row:
        def explore(self, *args, **kwargs):
            seen.append(_blas_threads())
            return "counts"

    seeds = runner.RemoteSeeds.__new__(runner.RemoteSeeds)
    seeds._built = (ThreadpoolController(), None, {"right-right": Row()})
    seeds.base_seed, seeds.estimator, seeds.counting, seeds.trrt = 0, None, None, None
    with threadpool_limits(limits=2, user_api="blas"):
        assert seeds("right-right", 3, False) == "counts"
        assert _blas_threads() == {2}
    assert seen == [{1}]
