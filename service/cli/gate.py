"""``regrasp gate check PLAN.json``: run the safety gate offline on a plan file.

Offline there is no approval and no robot: the approval/hash checks are skipped
unless ``--approved-sha256`` is given, and the start-state check is skipped unless
``--measured-q FILE.json`` is given. Every other check runs exactly as before a
dispatch. Exit codes: 0 passed, 1 vetoed, 2 unusable input.
"""

from __future__ import annotations

import json
import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path

import click

from .common import EXIT_USAGE, console, fail

EXIT_VETO = 1
#: Fields without which a document is not a plan file at all (bad input, exit 2, rather than a plan the gate vetoes).
PLAN_FILE_KEYS = ("schema", "status", "robot", "trajectory")


@click.group("gate")
def gate() -> None:
    """The safety gate (an independent recheck of a plan before it reaches the robot)."""


@gate.command("check")
@click.argument("plan_file", type=click.Path(dir_okay=False))
@click.option("--threshold-mm", type=float, default=None,
              help="CoM margin threshold (mm) for the samples; default: the plan's own. Never below the policy's floor.")
@click.option("--policy", "policy_file", type=click.Path(dir_okay=False), default=None,
              help="The site's safety policy file (regrasp.policy/1; also REGRASP_POLICY); default: the built-in "
                   "policy (30 mm floor), as at dispatch.")
@click.option("--approved-sha256", default=None, help="Also check the plan's hash against this approved one.")
@click.option("--measured-q", type=click.Path(exists=True, dir_okay=False), default=None,
              help="JSON {joint_names, q}: also check the first point against this robot state.")
@click.option("--json", "as_json", is_flag=True, help="Print the verdict as JSON.")
def check(plan_file: str, threshold_mm: float | None, approved_sha256: str | None, measured_q: str | None, as_json: bool,
          policy_file: str | None = None) -> None:
    """Check PLAN_FILE; exit 0 when it passes, 1 on a veto (naming the check and the first failing sample).

    The plan is judged by the site's safety policy as at dispatch: a plan made below its margin floor is
    vetoed, and every sample is checked against the larger of the threshold and the floor."""
    import os

    from schemas.policy import POLICY_ENV, PolicyError, policy_from

    try:
        policy = policy_from(policy_file if policy_file is not None else os.environ.get(POLICY_ENV))
    except PolicyError as exc:
        fail(str(exc))
    from rich.markup import escape

    from robot_bridge.gate import Approval, MeasuredState, SafetyGate

    path = Path(plan_file)
    if plan_file == "-":
        text = sys.stdin.read()
    else:
        try:
            text = path.read_text()
        except OSError as exc:
            fail(f"cannot read plan file {plan_file}: {exc}")
    try:
        plan = json.loads(text)
    except json.JSONDecodeError as exc:
        fail(f"plan file {plan_file} is not valid JSON: {exc}")
    if not isinstance(plan, dict):
        fail(f"{plan_file} is not a plan file (regrasp.plan/1): it holds a JSON {type(plan).__name__}, not an object")
    missing = [key for key in PLAN_FILE_KEYS if key not in plan]
    if missing:
        fail(f"{plan_file} is not a plan file (regrasp.plan/1): it has no {', '.join(missing)}")
    if threshold_mm is not None and not (threshold_mm >= 0 and threshold_mm < 1e4):
        fail(f"--threshold-mm {threshold_mm} must be a finite value >= 0")
    measured = None
    if measured_q:
        try:
            doc = json.loads(Path(measured_q).read_text())
            measured = MeasuredState(list(doc["joint_names"]), [float(v) for v in doc["q"]])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            fail(f"--measured-q {measured_q}: expected JSON with 'joint_names' and 'q': {exc}")
    approval = None
    if approved_sha256:
        approval = Approval(approved_sha256.lower(), datetime.now(timezone.utc) + timedelta(minutes=1))
    verdict = SafetyGate(policy=policy).check(
        plan, approval=approval, measured=measured, offline=True,
        threshold_m=None if threshold_mm is None else threshold_mm / 1000.0,
    )
    if as_json:
        click.echo(json.dumps(verdict.model_dump(mode="json"), indent=2, allow_nan=False))
    else:
        style = "bold green" if verdict.passed else "bold red"
        console.print(f"[{style}]{escape(verdict.summary())}[/]", highlight=False, soft_wrap=True)
        s = verdict.stats
        if "com_margin" in s and "min_margin_m" in s["com_margin"]:
            console.print(f"  min CoM margin {s['com_margin']['min_margin_m'] * 1000:.2f} mm "
                          f"(threshold {verdict.threshold_m * 1000:.2f} mm)", highlight=False)
        if "zmp" in s and "min_margin_m" in s["zmp"]:
            console.print(f"  min ZMP margin {s['zmp']['min_margin_m'] * 1000:.2f} mm", highlight=False)
        console.print(f"  {verdict.samples} samples in {verdict.elapsed_s * 1000:.1f} ms; skipped: {', '.join(verdict.skipped) or 'none'}",
                      highlight=False)
        if verdict.plan_sha256:
            console.print(f"  plan sha256 {verdict.plan_sha256}", highlight=False)
        console.print(f"  {policy.describe()}: margin floor {policy.margin_floor_m * 1000:.1f} mm", highlight=False)
    if verdict.check == "structure" and not verdict.passed and not isinstance(plan, dict):
        sys.exit(EXIT_USAGE)
    sys.exit(0 if verdict.passed else EXIT_VETO)
