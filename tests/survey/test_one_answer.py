"""One recommendation per task: the survey, `regrasp plan --hands auto` and the service's survey and plan jobs
give the same answer for the same task and seeds, computed once and then read from the cache.

The task is the small box (tests/data/small-box.yaml) with a small fixed-budget estimator in its own
``survey:`` field (two seeds of 60 states): that is the default estimator every path takes for it.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from service.cli.main import cli

DATA = Path(__file__).parent.parent / "data"


class Ctx:
    def progress(self, fraction: float, message: str) -> None:
        pass

    def cancelled(self) -> bool:
        return False


@pytest.fixture(scope="module")
def task_file(tmp_path_factory):
    doc = yaml.safe_load((DATA / "small-box.yaml").read_text())
    doc.update(hands="auto", survey={"until": "states", "states_per_seed": 60, "seeds_min": 2, "seeds_max": 2})
    path = tmp_path_factory.mktemp("one-answer") / "task.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path, doc


def test_survey_plan_auto_and_the_service_jobs_agree(task_file, tmp_path):
    from planner.jobs.entry import run_plan, run_survey

    path, doc = task_file
    res = CliRunner().invoke(cli, ["survey", str(path), "--json", "--workers", "1"])
    assert res.exit_code == 0, res.output
    survey = json.loads(res.stdout)
    best = survey["recommended"]
    assert best is not None and survey["stats"]["cache"] == "miss"
    assert all(r["seeds"] == 2 for r in survey["rows"] if r["ratio"] is not None)

    res = CliRunner().invoke(cli, ["plan", str(path), "--hands", "auto", "--quiet", "--out", str(tmp_path / "plan.json")])
    assert res.exit_code == 0, res.output
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["status"] == "solved" and plan["hands"] == best
    said = plan["stats"]["survey_recommendation"]
    assert said["recommended"] == best and said["cache"] == "hit" and said["task_key"] == survey["stats"]["task_key"]
    assert said["tie"] == bool(survey["indistinguishable"])
    if said["tie"]:
        assert "a tie" in said["note"]

    # The service's workers call these with the job's request (an inline scenario: the mesh-free box).
    inline = {k: v for k, v in doc.items()}
    job_survey = run_survey({"scenario": inline}, Ctx())
    assert job_survey["recommended"] == best and job_survey["stats"]["cache"] == "hit"
    assert [r["ratio"] for r in job_survey["rows"]] == [r["ratio"] for r in survey["rows"]]
    job_plan = run_plan({"scenario": inline, "hands": "auto"}, Ctx())
    assert job_plan["hands"] == best


def test_another_seed_is_another_task(task_file):
    """The cache key is the resolved scenario: a different first seed is surveyed afresh."""
    from planner.scene.scenarios import load_scenario, with_overrides
    from planner.survey.cache import task_key

    path, _ = task_file
    sc = load_scenario(path)
    assert task_key(sc, "x") != task_key(with_overrides(sc, seed=2), "x")
    assert task_key(sc, "x") == task_key(with_overrides(sc, hands="left-left"), "x")  # the plan's hands do not matter
    assert task_key(sc, "x") != task_key(with_overrides(sc, threshold_m=0.02), "x")


def test_the_key_covers_the_limits_the_robot_spec_and_the_planner_code(task_file, hrp5p, tmp_path):
    """A survey with the limits off, a robot whose effort limits differ, or changed planner code is another
    task: the key hashes them, the code found by package so that a module that moves is still hashed."""
    import dataclasses

    from planner.scene.scenarios import load_scenario
    from planner.survey import cache
    from planner.survey.cache import code_digest, code_version, robot_fingerprint, survey_code_files, task_key

    path, _ = task_file
    sc = load_scenario(path)
    fp = robot_fingerprint(hrp5p)
    assert task_key(sc, fp, limits=True) != task_key(sc, fp, limits=False)
    weak = dataclasses.replace(hrp5p, spec=hrp5p.spec.model_copy(
        update={"effort_limits": {**hrp5p.spec.effort_limits, "RWRP": 12.0}}))
    assert robot_fingerprint(weak) != fp
    hashed = {p.relative_to(cache.PLANNER_ROOT).as_posix() for p in survey_code_files()}
    for module in ("survey/counting.py", "survey/estimator.py", "survey/limits.py", "motion/trrt.py",
                   "stability/effort.py", "stability/evaluator.py", "regrasp/state_checker.py", "scene/collision.py"):
        assert module in hashed, module
    # a copy of the code hashes the same; one changed module makes another version
    copy = tmp_path / "planner"
    for p in survey_code_files():
        target = copy / p.relative_to(cache.PLANNER_ROOT)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(p.read_bytes())
    assert code_digest(copy) == code_version()
    (copy / "survey" / "counting.py").write_text((copy / "survey" / "counting.py").read_text() + "\n# changed\n")
    assert code_digest(copy) != code_version()



def test_a_hands_auto_plan_is_the_same_whether_its_survey_ran_or_was_cached(tmp_path, monkeypatch):
    """The seed decides the plan: a `hands: auto` plan whose survey runs in the same process (an empty cache) and
    the same plan once the survey is cached give the same trajectory. The staggered task with a small survey (two
    key-path seeds, two seeds of 60 states) is one where a search that inherited the survey's scratch took another
    path."""
    from planner.jobs.plan_job import plan_scenario
    from planner.scene.scenarios import load_scenario

    monkeypatch.setenv("REGRASP_SURVEY_CACHE_DIR", str(tmp_path / "surveys"))
    scenario = load_scenario("staggered")
    small = scenario.survey.model_copy(update={"until": "states", "states_per_seed": 60, "seeds_min": 2,
                                               "seeds_max": 2, "key_path_pool": 2})
    scenario = scenario.model_copy(update={"hands": "auto", "survey": small})
    first = plan_scenario(scenario)
    second = plan_scenario(scenario)
    assert first["stats"]["survey_recommendation"]["cache"] == "miss"
    assert second["stats"]["survey_recommendation"]["cache"] == "hit"
    assert first["status"] == second["status"] == "solved"
    assert first["hands"] == second["hands"]
    assert first["trajectory"] == second["trajectory"]
