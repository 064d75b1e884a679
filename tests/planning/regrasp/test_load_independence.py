"""Runs do not depend on the machine's load: seeds and iteration caps decide a plan, never the clock
(docs/contract.md section 3). A time limit is only the user's own budget; the built-ins carry none."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from planner.scene.scenarios import builtin_names, resolve_scenario
from planner.termination import Termination
from robot_bridge.process_tuning import cpu_competitor_command

ROOT = Path(__file__).resolve().parents[3]
SMALL_BOX = ROOT / "tests" / "data" / "small-box.yaml"

#: Plans the small task with the default limits (its file's own time budget taken out) and prints the
#: SHA-256 of every trajectory point's q.
PLAN = (
    "import hashlib, json, sys\n"
    "from planner.scene.scenarios import load_scenario\n"
    "from planner.jobs.plan_job import PlanOptions, plan_scenario\n"
    "sc = load_scenario(sys.argv[1])\n"
    "sc = sc.model_copy(update={'limits': sc.limits.model_copy(update={'time_s': None})})\n"
    "doc = plan_scenario(sc, PlanOptions())\n"
    "qs = json.dumps([p['q'] for p in doc.get('trajectory', [])])\n"
    "print(json.dumps({'status': doc['status'], 'points': len(doc.get('trajectory', [])),"
    " 'q_sha256': hashlib.sha256(qs.encode()).hexdigest()}))\n"
)


def _plan_once() -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", PLAN, str(SMALL_BOX)], capture_output=True, text=True, env=env,
                          timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_built_in_scenarios_carry_no_time_limit():
    for name in builtin_names():
        limits = resolve_scenario(name).limits
        assert limits.time_s is None, f"{name}: limits.time_s {limits.time_s}"
        termination = Termination.of_limits(limits)
        assert not termination.has_deadline and termination.max_iterations == limits.max_iterations
        assert not termination.should_stop()


def test_a_user_time_limit_maps_onto_the_termination():
    sc = resolve_scenario("upright")
    limited = sc.limits.model_copy(update={"time_s": 5.0})
    termination = Termination.of_limits(limited, started=100.0)
    assert termination.deadline == pytest.approx(105.0) and termination.has_deadline
    assert termination.with_iterations(7).deadline == termination.deadline
    assert math.isinf(Termination.of_limits(sc.limits).time_limit_s)


@pytest.mark.timeout(900)
def test_the_same_plan_on_a_quiet_and_on_a_loaded_machine():
    """Two CPU-bound competitors on a 2-core machine slow the plan down; its trajectory stays the same."""
    quiet = _plan_once()
    assert quiet["status"] == "solved" and quiet["points"] > 0
    spinners = [subprocess.Popen(cpu_competitor_command()) for _ in range(2)]
    try:
        loaded = _plan_once()
    finally:
        for p in spinners:
            p.kill()
            p.wait()
    assert loaded == quiet
