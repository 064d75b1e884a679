"""Table definitions of the job store (portable: SQLite and PostgreSQL).

``jobs`` holds one row per job (state, progress, approval, provenance, lease of
the runner that claims it, planning time and outcome); ``job_results`` the result documents, kept apart so
the rows scanned by claims and listings stay small; ``job_events`` the ordered
history that feeds the SSE stream and the audit file.
"""

from __future__ import annotations

from datetime import datetime, timezone

import sqlalchemy as sa
from sqlalchemy.types import TypeDecorator

metadata = sa.MetaData()


class UTCDateTime(TypeDecorator):
    """Timestamps stored in UTC and always read back timezone-aware (SQLite drops the zone)."""

    impl = sa.DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: sa.Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime given to the job store; use UTC-aware datetimes")
        return value.astimezone(timezone.utc)

    def process_result_value(self, value: datetime | None, dialect: sa.Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=timezone.utc) if value.tzinfo is None else value.astimezone(timezone.utc)


jobs = sa.Table(
    "jobs",
    metadata,
    sa.Column("seq", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("id", sa.String(36), nullable=False, unique=True),
    sa.Column("kind", sa.String(16), nullable=False),
    sa.Column("state", sa.String(16), nullable=False, index=True),
    sa.Column("progress", sa.Float, nullable=False, default=0.0),
    sa.Column("message", sa.Text),
    sa.Column("submitter", sa.String(128), nullable=False),
    sa.Column("request", sa.JSON, nullable=False),
    sa.Column("request_sha256", sa.String(64), nullable=False),
    sa.Column("idempotency_key", sa.String(255)),
    sa.Column("error", sa.JSON),
    sa.Column("plan_sha256", sa.String(64)),
    sa.Column("approved_by", sa.String(128)),
    sa.Column("approved_at", UTCDateTime),
    sa.Column("approval_expires_at", UTCDateTime),
    sa.Column("approved_sha256", sa.String(64)),
    sa.Column("approval_comment", sa.Text),
    sa.Column("cancel_requested", sa.Boolean, nullable=False, default=False),
    sa.Column("stop_requested", sa.Boolean, nullable=False, default=False),
    sa.Column("attempts", sa.Integer, nullable=False, default=0),
    sa.Column("seed", sa.BigInteger),
    sa.Column("code_version", sa.String(128)),
    sa.Column("robot", sa.String(64)),
    sa.Column("robot_sha256", sa.String(64)),
    sa.Column("library_versions", sa.JSON),
    sa.Column("owner", sa.String(255)),
    sa.Column("lease_expires_at", UTCDateTime),
    sa.Column("audit_path", sa.Text),
    sa.Column("audit_head", sa.String(64)),
    sa.Column("audit_event_id", sa.Integer),
    sa.Column("audit_closed", sa.Boolean),
    sa.Column("created_at", UTCDateTime, nullable=False),
    sa.Column("updated_at", UTCDateTime, nullable=False),
    sa.Column("started_at", UTCDateTime),
    sa.Column("finished_at", UTCDateTime),
    # Written when planning ends (by the runner, or by recovery): the source of the duration/outcome metrics.
    sa.Column("planning_s", sa.Float),
    sa.Column("planning_outcome", sa.String(16)),
    # A plan job planned below the safety policy's floor: a comparison, never approved or dispatched.
    sa.Column("comparison", sa.Boolean),
    sa.UniqueConstraint("submitter", "idempotency_key", name="uq_jobs_submitter_idempotency_key"),
    # The two aggregates of every /metrics scrape (JobStore.count_by_state, planning_stats) read only these.
    sa.Index("ix_jobs_kind_state", "kind", "state"),
    sa.Index("ix_jobs_planning_stats", "planning_outcome", "kind", "planning_s"),
)

job_results = sa.Table(
    "job_results",
    metadata,
    sa.Column("job_id", sa.String(36), sa.ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True),
    sa.Column("result", sa.Text, nullable=False),
)

job_events = sa.Table(
    "job_events",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("job_id", sa.String(36), sa.ForeignKey("jobs.id", ondelete="CASCADE"), nullable=False, index=True),
    sa.Column("at", UTCDateTime, nullable=False),
    sa.Column("kind", sa.String(32), nullable=False),
    sa.Column("state", sa.String(16)),
    sa.Column("progress", sa.Float),
    sa.Column("message", sa.Text),
    sa.Column("data", sa.JSON),
)
