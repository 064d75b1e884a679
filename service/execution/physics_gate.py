"""The safety policy's physics check at dispatch (``require_physics_pass``, ``min_cop_margin_m``).

The dry run is the risk card's (service.jobs.risk): the plan played in the MuJoCo twin when it was planned, bound
to the plan's hash. This check reads that record; it runs no physics itself, and the safety gate stays free of
MuJoCo. A plan without a dry run for its own hash, or whose dry run fell, faulted, or kept a smaller CoP margin
than the policy's floor, is not dispatched.
"""

from __future__ import annotations

from typing import Any

from schemas.policy import SafetyPolicy


def physics_problem(policy: SafetyPolicy, card: dict[str, Any] | None, plan_sha256: str) -> str | None:
    """Why the policy refuses to dispatch this plan on its physics dry run, or None (the policy may not ask)."""
    if not policy.require_physics_pass:
        return None
    physics = (card or {}).get("physics") if isinstance(card, dict) else None
    if not isinstance(physics, dict):
        return "the safety policy requires a physics dry run, and this plan has none"
    if "error" in physics:
        return f"the safety policy requires a physics dry run, and this plan's failed: {physics['error']}"
    report = physics.get("report") or {}
    if report.get("plan_sha256") != plan_sha256 or card.get("plan_sha256") not in (None, plan_sha256):
        return "the physics dry run on record is not this plan's (its hash differs)"
    fault = report.get("fault")
    if fault:
        kind = "fell" if report.get("fell") else f"faulted ({fault.get('kind')})"
        return (f"the physics dry run {kind} at {float(fault.get('at_s', 0.0)):.2f} s: {fault.get('detail')}; "
                "the safety policy requires it to stand")
    floor = policy.min_cop_margin_m
    margin = report.get("min_cop_margin_m")
    if floor is not None and (margin is None or float(margin) < floor):
        shown = "none" if margin is None else f"{float(margin) * 1000:.1f} mm"
        return (f"the physics dry run's smallest CoP margin ({shown} at {report.get('min_cop_margin_at_s')} s) is "
                f"below the safety policy's min_cop_margin_m ({floor * 1000:.1f} mm)")
    return None


def site_policy(svc: Any) -> SafetyPolicy:
    """The service's safety policy, with the physics dry run required when the service's own setting
    (``require_physics_pass``, on under ``--dev`` and in the demo) asks for it: a setting can add the rule, never
    lift the policy's."""
    from schemas.policy import default_policy

    policy = getattr(svc, "policy", None)
    if not isinstance(policy, SafetyPolicy):
        policy = default_policy()
    settings = svc.settings
    if (getattr(settings, "require_physics_pass", False) or getattr(settings, "dev", False)) \
            and not policy.require_physics_pass:
        policy = policy.model_copy(update={"require_physics_pass": True})
    return policy


def stored_card(svc: Any, job_id: str, plan_sha256: str) -> dict[str, Any] | None:
    """The job's risk card for ``plan_sha256`` as stored with its events (the planned event, or a later note)."""
    cursor = 0
    while True:
        page = svc.store.events_after(job_id, cursor, 500)
        for ev in page:
            card = (ev.get("data") or {}).get("risk")
            if isinstance(card, dict) and card.get("plan_sha256") == plan_sha256:
                return card
        if len(page) < 500:
            return None
        cursor = page[-1]["id"]


def dispatch_physics(svc: Any, row: dict[str, Any]) -> tuple[str | None, dict[str, Any] | None]:
    """Why the site's policy refuses to dispatch this approved job on its physics dry run (or None), and the dry
    run's report (``regrasp.simreport/1``) that the bridge's gate is given to judge on its own, when the policy
    requires one and the plan has it (None otherwise: the gate is then not asked to judge physics)."""
    policy = site_policy(svc)
    if not policy.require_physics_pass:
        return None, None
    sha = row.get("approved_sha256") or row.get("plan_sha256") or ""
    card = stored_card(svc, row["id"], sha)
    physics = (card or {}).get("physics") if isinstance(card, dict) else None
    report = physics.get("report") if isinstance(physics, dict) else None
    return physics_problem(policy, card, sha), report if isinstance(report, dict) else None
