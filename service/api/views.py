"""Job rows -> the wire model of schemas/jobs.py."""

from __future__ import annotations

from typing import Any

from schemas.jobs import Approval, Job, JobErrorInfo, Provenance


def job_view(row: dict[str, Any], result: dict[str, Any] | None = None) -> Job:
    approval = None
    if row.get("approved_by") and row.get("approved_at") and row.get("approval_expires_at"):
        approval = Approval(approved_by=row["approved_by"], approved_at=row["approved_at"],
                            expires_at=row["approval_expires_at"], plan_sha256=row["approved_sha256"] or "",
                            comment=row.get("approval_comment"))
    error = row.get("error")
    return Job(
        id=row["id"], kind=row["kind"], state=row["state"], progress=float(row.get("progress") or 0.0),
        message=row.get("message"), submitter=row["submitter"], request=row["request"], result=result,
        error=JobErrorInfo(**{k: v for k, v in error.items() if k in ("code", "message")}) if error else None,
        plan_sha256=row.get("plan_sha256"), approval=approval, comparison=bool(row.get("comparison")),
        cancel_requested=bool(row.get("cancel_requested")),
        attempts=int(row.get("attempts") or 0),
        provenance=Provenance(seed=row.get("seed"), code_version=row.get("code_version"), robot=row.get("robot"),
                              robot_sha256=row.get("robot_sha256"), library_versions=row.get("library_versions") or {}),
        audit_head=row.get("audit_head"), created_at=row["created_at"], updated_at=row["updated_at"],
        started_at=row.get("started_at"), finished_at=row.get("finished_at"),
    )
