"""The risk card: what an approver should know about a plan before signing it.

At planning time the safety gate (robot_bridge.gate, the independent channel: its own URDF
kinematics, never the planner's numbers) dry-runs the plan offline, exactly as it will at
dispatch minus the approval and measured-state checks. The card reports its verdict and the
worst moments it found: the smallest CoM margin headroom above the threshold and the smallest
ZMP margin, each with its time, plan point, segment (kind and hand). Effort headroom comes
from the plan's own ``effort_ratio`` (the gate has no torque model); it is labelled so.

The card also carries the physics dry run (robot_bridge.physics, CONTRACT 9): the plan played in the
MuJoCo twin at speed 1 and mass scale 1, bound to the plan's hash: whether the robot stood, its
smallest centre-of-pressure margin, when and in which segment. The safety policy's
``require_physics_pass`` dispatches only plans whose dry run stood (service.execution.physics_gate).

The card is computed where the plan is (the worker), stored with the job's ``planned`` event,
and served by ``GET /v1/jobs/{id}/risk`` (service.api.risk) together with the gate's verdict at
dispatch and, when the store holds one, a comparison with the same task planned at 0 mm.
"""

from __future__ import annotations

import functools
import math
from typing import Any

#: Version of the card's layout (a reader can tell cards apart from older ones).
RISK_SCHEMA = "regrasp.risk/1"


@functools.lru_cache(maxsize=1)
def _gate() -> Any:
    """One gate per process: it parses each robot's URDF once. It judges by the site's safety policy
    (``REGRASP_POLICY``, else the built-in one), as the gate at dispatch does."""
    import os

    from robot_bridge.gate import SafetyGate
    from schemas.policy import POLICY_ENV, policy_from

    return SafetyGate(policy=policy_from(os.environ.get(POLICY_ENV)))


def _segment_at(plan: dict[str, Any], point: int | None) -> dict[str, Any] | None:
    if point is None:
        return None
    for i, seg in enumerate(plan.get("segments") or []):
        if seg.get("first", 0) <= point <= seg.get("last", -1):
            return {"index": i, "kind": seg.get("kind"), "hand": seg.get("hand")}
    return None


def _moment(plan: dict[str, Any], sample: int | None, per_point: int) -> dict[str, Any]:
    """Time, plan point and segment of a gate sample."""
    if sample is None:
        return {"sample": None, "point": None, "t": None, "segment": None}
    n = len(plan.get("trajectory") or [])
    point = min(sample // max(per_point, 1), max(n - 1, 0))
    dt = float(plan.get("dt_s") or 0.0)
    return {"sample": int(sample), "point": int(point), "t": sample * dt / max(per_point, 1),
            "segment": _segment_at(plan, point)}


def _effort(plan: dict[str, Any]) -> dict[str, Any] | None:
    """The largest effort ratio of the plan (planner's figure) and where; None when the plan has none."""
    best, at = -math.inf, None
    for i, p in enumerate(plan.get("trajectory") or []):
        r = p.get("effort_ratio")
        if isinstance(r, (int, float)) and math.isfinite(r) and r > best:
            best, at = float(r), i
    if at is None:
        return None
    dt = float(plan.get("dt_s") or 0.0)
    return {"max_ratio": best, "headroom": 1.0 - best, "point": at, "t": at * dt, "segment": _segment_at(plan, at),
            "source": "plan effort_ratio (the planner's static torques; the gate checks no torques)"}


def risk_card(plan: dict[str, Any], plan_text: str | bytes | None = None) -> dict[str, Any]:
    """The card of a solved plan: the gate's offline verdict and the plan's worst moments.

    ``plan_text`` (the plan's canonical JSON) lets the gate hash and parse the bytes it was given,
    as at dispatch; without it the gate checks the dict.
    """
    gate = _gate()
    physics = physics_dry_run(plan)  # given to the gate too: a policy that requires it judges this run
    report = physics.get("report")
    if plan_text is not None:
        verdict, _ = gate.check_json(plan_text, offline=True, physics=report)
    else:
        verdict = gate.check(plan, offline=True, physics=report)
    stats = verdict.stats or {}
    per_point = int((stats.get("time") or {}).get("samples_per_point") or 1)
    threshold = verdict.threshold_m if verdict.threshold_m is not None else plan.get("threshold_m")
    com = stats.get("com_margin") or {}
    zmp = stats.get("zmp") or {}
    card: dict[str, Any] = {
        "schema": RISK_SCHEMA,
        "plan_sha256": verdict.plan_sha256,
        "threshold_m": threshold,
        # the site's floor the gate judged by: headroom figures are measured against max(task threshold, floor)
        "margin_floor_m": gate.policy.margin_floor_m,
        "gate": {"passed": verdict.passed, "check": verdict.check, "message": verdict.message,
                 "failed_at": _moment(plan, verdict.sample_index, per_point) if not verdict.passed else None,
                 "samples": verdict.samples, "checks_passed": verdict.checks_passed, "skipped": verdict.skipped,
                 "elapsed_s": verdict.elapsed_s},
        "com_margin": None,
        "zmp": None,
        "effort": _effort(plan),
        "planner_min_margin_m": plan.get("min_margin_m"),
        "physics": physics,
    }
    if "min_margin_m" in com:
        m = float(com["min_margin_m"])
        card["com_margin"] = {"min_margin_m": m, "headroom_m": None if threshold is None else m - float(threshold),
                              **_moment(plan, com.get("at_sample"), per_point),
                              "hand": _holding_at(plan, com.get("at_sample"), per_point)}
    if "min_margin_m" in zmp:
        card["zmp"] = {"min_margin_m": float(zmp["min_margin_m"]), **_moment(plan, zmp.get("at_sample"), per_point)}
    return card


def physics_dry_run(plan: dict[str, Any]) -> dict[str, Any]:
    """The plan in the physics twin at speed 1 and mass scale 1: the simulation report (regrasp.simreport/1)
    plus where its smallest CoP margin (or its fault) happened and whether it stood; ``error`` when the twin could
    not play it (the card still goes out: a missing dry run fails the policy's physics check, never passes it)."""
    try:
        from robot_bridge.physics.simulate import simulate

        report = simulate(plan).report
    except Exception as exc:  # noqa: BLE001 - the card is advice; the policy check treats an error as no pass
        return {"error": f"the physics dry run could not be made: {type(exc).__name__}: {exc}"}
    fault = report.get("fault")
    at = fault["at_s"] if fault else report.get("min_cop_margin_at_s")
    dt = float(plan.get("dt_s") or 0.0)
    n = len(plan.get("trajectory") or [])
    point = None if at is None or dt <= 0 or n == 0 else int(min(max(round(at / dt), 0), n - 1))
    return {"stood": fault is None, "at": {"t": at, "point": point, "segment": _segment_at(plan, point)},
            "report": report}


def _holding_at(plan: dict[str, Any], sample: int | None, per_point: int) -> str | None:
    """Which hand holds the object at that sample (``none`` when it rests on a table)."""
    if sample is None:
        return None
    traj = plan.get("trajectory") or []
    if not traj:
        return None
    return traj[min(sample // max(per_point, 1), len(traj) - 1)].get("holding")


def safe_risk_card(plan: dict[str, Any], plan_text: str | bytes | None = None) -> dict[str, Any]:
    """:func:`risk_card`, or a card that says why it could not be made (a plan is never lost for its card)."""
    try:
        return risk_card(plan, plan_text)
    except Exception as exc:  # noqa: BLE001 - the card is advice; the gate at dispatch still decides
        return {"schema": RISK_SCHEMA, "error": f"the risk card could not be computed: {type(exc).__name__}: {exc}"}


def compare_with_unconstrained(plan: dict[str, Any], free: dict[str, Any]) -> dict[str, Any]:
    """How the plan compares with the same task planned at 0 mm (the unconstrained planner)."""
    thr = float(plan.get("threshold_m") or 0.0)
    free_min = free.get("min_margin_m")
    same = [p.get("q") for p in plan.get("trajectory") or []] == [p.get("q") for p in free.get("trajectory") or []]
    return {"min_margin_m": plan.get("min_margin_m"), "unconstrained_min_margin_m": free_min,
            "unconstrained_breaks_threshold": isinstance(free_min, (int, float)) and free_min < thr - 1e-4,
            "plans_differ": not same, "unconstrained_hands": free.get("hands"),
            "unconstrained_duration_s": _duration(free), "duration_s": _duration(plan)}


def _duration(plan: dict[str, Any]) -> float | None:
    traj = plan.get("trajectory") or []
    return float(traj[-1].get("t", 0.0)) if traj else None
