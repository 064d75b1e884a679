"""The README's first command, `regrasp demo`, as a test: every step for real on loopback."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import pytest
from plan_checker import check_plan

from service.audit.verify import verify


@pytest.mark.host_pauses(limit_s=0.5, attempts=2)
def test_demo_runs_end_to_end(tmp_path):
    out = tmp_path / "demo"
    # The survey cache the demo's service fills (it takes REGRASP_SURVEY_CACHE_DIR when set, as here).
    cache_env = {**os.environ, "REGRASP_SURVEY_CACHE_DIR": str(tmp_path / "survey-cache")}
    proc = subprocess.run([sys.executable, "-m", "service.cli.main", "demo", "--out", str(out)],
                          capture_output=True, text=True, timeout=900, env=cache_env)
    logs = "".join(f"\n--- {log.name}\n" + log.read_text()[-3000:] for log in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:] + logs
    for name in ("upright", "staggered", "crouched", "one-legged"):
        assert (out / f"stance-{name}.png").is_file()
    plan = json.loads((out / "plan.json").read_text())
    survey = json.loads((out / "survey.json").read_text())
    assert plan["status"] == "solved" and plan["hands"] == survey["recommended"]
    assert check_plan(plan, sample_every=5).errors == []
    assert {r["hands"] for r in survey["rows"]} == {"left-left", "right-right", "left-right", "right-left"}
    # One answer per task: the demo surveys with the task's own estimator, so `regrasp survey` finds the demo's
    # answer under its own key for the task (the key hashes the resolved scenario and the estimator; a survey is
    # decided by them, tests/survey/test_seed_map.py) and gives the same rows.
    alone = subprocess.run([sys.executable, "-m", "service.cli.main", "survey", "--scenario", "upright", "--json"],
                           capture_output=True, text=True, timeout=900, env=cache_env)
    assert alone.returncode == 0, alone.stderr[-2000:]
    own = json.loads(alone.stdout)
    assert own["stats"].get("cache") == "hit", "regrasp survey keys the task differently from the demo"
    assert own["estimator"] == survey["estimator"] and own["estimator"]["until"] == "solved"
    assert own["recommended"] == survey["recommended"] and own["indistinguishable"] == survey["indistinguishable"]
    assert [(r["hands"], r["stable"], r["unstable"], r["seeds"]) for r in own["rows"]] == [
        (r["hands"], r["stable"], r["unstable"], r["seeds"]) for r in survey["rows"]]
    # The audit files (the survey's and the plan's) are where the service wrote them, once: no copy beside them.
    audits = list(out.rglob("*.mcap"))
    assert len(audits) == 2 and {a.parent for a in audits} == {out / "service-data" / "audit"}
    plan_audit = out / "service-data" / "audit" / f"{plan_job_id(proc.stdout)}.mcap"
    result = verify(plan_audit)
    assert result.exit_code == 0 and result.finished
    _check_one_timeline(plan_audit)
    _check_never_silent(proc.stdout)
    big = {}
    for f in out.rglob("*"):
        if f.is_file() and f.stat().st_size > 100_000:
            digest = hashlib.sha256(f.read_bytes()).hexdigest()
            assert digest not in big, f"{f} duplicates {big[digest]}"
            big[digest] = f
    assert "succeeded" in proc.stdout  # the summary table shows the execution result
    # The personas of `regrasp serve --dev`, and each step printed as it runs (the execution's progress too).
    assert "carol approves" in proc.stdout and "bob dispatches" in proc.stdout
    assert "safety gate: passed" in proc.stdout and "executing: 50 %" in proc.stdout and "execution finished: succeeded" in proc.stdout
    for png in ("plan-com-trace.png", "plan-margin.png", "survey-bars.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"


def _check_one_timeline(path) -> None:
    """The plan replayed on the execution's timeline overlaps what the robot reported, and the robot's
    measured joint states are kept at 50 or more per second during the execution (CONTRACT 7)."""
    from mcap.reader import make_reader

    times: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(
                topics=["/executed_plan/joint_states", "/robot/joint_states", "/plan/joint_states"]):
            times.setdefault(channel.topic, []).append(message.publish_time)
    replayed, measured = sorted(times["/executed_plan/joint_states"]), sorted(times["/robot/joint_states"])
    assert replayed[0] < measured[-1] and measured[0] < replayed[-1], "planned and executed robots never overlap"
    overlap = min(replayed[-1], measured[-1]) - max(replayed[0], measured[0])
    assert overlap > 0.8 * (measured[-1] - measured[0])
    span_s = (measured[-1] - measured[0]) / 1e9
    assert len(measured) / span_s >= 50, f"{len(measured)} measured states over {span_s:.1f} s"


def _check_never_silent(stdout: str) -> None:
    """Each of the demo's lines starts with its time (s since the start): no gap of more than 3 s."""
    import re

    stamps = [float(m.group(1)) for m in re.finditer(r"^\s+(\d+\.\d) s ", stdout, flags=re.M)]
    assert len(stamps) > 10
    gaps = [b - a for a, b in zip(stamps, stamps[1:])]
    assert max(gaps) <= 3.0, f"the demo was silent for {max(gaps):.1f} s"


def plan_job_id(stdout: str) -> str:
    """The plan job's id, from the demo's list of artefacts ("audit: .../service-data/audit/<job>.mcap")."""
    line = next(line for line in stdout.splitlines() if line.strip().startswith("audit:") and ".mcap" in line)
    return line.strip().rsplit("/", 1)[1].removesuffix(".mcap")


@pytest.mark.host_pauses(limit_s=0.5, attempts=2)
def test_the_demo_with_talos_runs_its_own_upright_task(tmp_path):
    """`regrasp demo --robot talos`: TALOS's stances, then talos-upright (TALOS's version of the paper's task)
    surveyed, planned, gated and played by the controller simulator of TALOS; about 30 s."""
    pytest.importorskip("cmeel", reason="TALOS needs the example-robot-data package (the `talos` extra)")
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "service.cli.main", "demo", "--robot", "talos", "--out", str(out),
                           "--survey-states", "100"], capture_output=True, text=True, timeout=600)
    logs = "".join(f"\n--- {log.name}\n" + log.read_text()[-3000:] for log in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:] + logs
    plan = json.loads((out / "plan.json").read_text())
    survey = json.loads((out / "survey.json").read_text())
    assert plan["robot"]["name"] == survey["robot"]["name"] == "talos" and plan["scenario"]["name"] == "talos-upright"
    # hands: auto starts at the recommendation, or on a tie at the first of the tied rows in the tie order
    # (left-left, right-right, left-right, right-left), and keeps the first configuration that plans.
    tied = {survey["recommended"], *survey["indistinguishable"]}
    first = next(h for h in ("left-left", "right-right", "left-right", "right-left") if h in tied)
    runs = plan["stats"]["configurations"]
    tried = list(runs)
    assert plan["status"] == "solved" and tried[0] == first
    assert plan["hands"] == next(h for h in tried if runs[h]["status"] == "solved")
    assert check_plan(plan, sample_every=5, robot_spec="robot_data/talos.yaml").errors == []
    assert '"robot_id": "talos"' in (out / "controller-sim.log").read_text()  # the simulator plays TALOS
    assert "Scenario talos-upright with talos" in proc.stdout and "safety gate: passed" in proc.stdout
    assert "execution finished: succeeded" in proc.stdout
    plan_audit = out / "service-data" / "audit" / f"{plan_job_id(proc.stdout)}.mcap"
    assert verify(plan_audit).exit_code == 0
