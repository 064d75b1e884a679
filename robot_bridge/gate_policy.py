"""The gate's checks of the site's safety policy (:mod:`schemas.policy`): what a plan must meet whatever it asked for.

Part of the gate (:mod:`robot_bridge.gate`). A plan made for a CoM margin below the policy's floor was not
planned for this site (a comparison, or a request that tried to lower it) and is vetoed before anything
else is computed; the margin every sample is then checked against is the larger of the plan's threshold
and the floor. The held object's mass and the plan's speed are capped; a policy that requires the physics
dry run vetoes a plan without a run of the twin that stood.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from schemas.policy import SafetyPolicy

from .gate_context import _Context
from .gate_parse import _Parsed
from .gate_types import Veto


def check_policy_threshold(ctx: _Context, p: _Parsed, policy: SafetyPolicy, threshold_m: float | None) -> float:
    """The margin the samples are checked against; a veto when the plan was made below the floor.

    ``threshold_m`` (a caller's own, e.g. ``regrasp gate check --threshold-mm``) replaces the plan's threshold
    for the samples, never below the floor; the floor veto always judges the plan's own threshold."""
    thr = p.threshold
    if not math.isfinite(thr) or thr < 0:
        raise Veto("structure", f"threshold {thr!r} m must be finite and >= 0")
    if policy.below_floor(thr):
        raise Veto("policy", f"the plan was made for a {thr * 1000:.1f} mm CoM margin, below the "
                   f"{policy.margin_floor_m * 1000:.1f} mm floor of the {policy.describe()}: it was not planned for "
                   "this site (a comparison is never dispatched); plan it at the floor or above")
    if threshold_m is not None:
        thr = float(threshold_m)
        if not math.isfinite(thr) or thr < 0:
            raise Veto("structure", f"threshold {thr!r} m must be finite and >= 0")
    effective = policy.effective_threshold_m(thr)
    ctx.note("policy", sha256=policy.sha256(), margin_floor_m=policy.margin_floor_m, plan_threshold_m=p.threshold,
             threshold_m=effective)
    return effective


def check_policy_limits(ctx: _Context, p: _Parsed, policy: SafetyPolicy, physics: dict[str, Any] | None) -> None:
    """The policy's caps on the held object's mass and on the plan's speed, and its physics dry run."""
    held = bool(np.any(p.holding != 0))
    if policy.max_object_mass_kg is not None and held and p.mass > policy.max_object_mass_kg:
        first = int(np.flatnonzero(p.holding != 0)[0])
        raise Veto("policy", f"the plan holds a {p.mass:.2f} kg object; the {policy.describe()} allows at most "
                   f"{policy.max_object_mass_kg:.2f} kg", first * ctx.S)
    if p.speed_scale is not None and p.speed_scale > policy.max_speed_scale + 1e-12:
        raise Veto("policy", f"the plan is timed at speed_scale {p.speed_scale:g}; the {policy.describe()} allows at "
                   f"most {policy.max_speed_scale:g}")
    if policy.require_physics_pass:
        _check_physics(ctx, policy, physics)
    ctx.passed("policy", max_object_mass_kg=policy.max_object_mass_kg, max_speed_scale=policy.max_speed_scale,
               speed_scale=p.speed_scale)


def _check_physics(ctx: _Context, policy: SafetyPolicy, report: dict[str, Any] | None) -> None:
    """The physics dry run (``regrasp.simreport/1`` of this plan's hash) stood, with the policy's CoP floor.

    The gate runs no physics: without a report given to it the check is skipped (and says so); the service
    refuses to dispatch a plan without its risk card's dry run (service.execution.physics_gate)."""
    if report is None:
        ctx.skip("physics_dry_run")
        return
    if ctx.plan_sha256 is not None and report.get("plan_sha256") != ctx.plan_sha256:
        raise Veto("policy", f"the physics dry run given is of plan {report.get('plan_sha256')!r}, not of this one")
    if report.get("fell") or report.get("fault"):
        raise Veto("policy", f"the physics dry run did not stand: {report.get('fault') or 'the robot fell'}")
    cop = report.get("min_cop_margin_m")
    floor = policy.min_cop_margin_m
    if floor is not None and (not isinstance(cop, (int, float)) or not math.isfinite(cop) or cop < floor):
        raise Veto("policy", f"the physics dry run's smallest CoP margin is {cop!r} m; the {policy.describe()} "
                   f"needs {floor * 1000:.1f} mm")
