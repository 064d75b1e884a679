"""Initial job store: jobs, job_results, job_events.

Revision ID: 0001
Revises:
"""

import sqlalchemy as sa
from alembic import op

from service.store.tables import UTCDateTime

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "jobs",
        sa.Column("seq", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("id", sa.String(36), nullable=False, unique=True),
        sa.Column("kind", sa.String(16), nullable=False),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("progress", sa.Float, nullable=False),
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
        sa.Column("cancel_requested", sa.Boolean, nullable=False),
        sa.Column("stop_requested", sa.Boolean, nullable=False),
        sa.Column("attempts", sa.Integer, nullable=False),
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
        sa.UniqueConstraint("submitter", "idempotency_key", name="uq_jobs_submitter_idempotency_key"),
    )
    op.create_index("ix_jobs_state", "jobs", ["state"])
    op.create_table(
        "job_results",
        sa.Column("job_id", sa.String(36), sa.ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("result", sa.Text, nullable=False),
    )
    op.create_table(
        "job_events",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("job_id", sa.String(36), sa.ForeignKey("jobs.id", ondelete="CASCADE"), nullable=False),
        sa.Column("at", UTCDateTime, nullable=False),
        sa.Column("kind", sa.String(32), nullable=False),
        sa.Column("state", sa.String(16)),
        sa.Column("progress", sa.Float),
        sa.Column("message", sa.Text),
        sa.Column("data", sa.JSON),
    )
    op.create_index("ix_job_events_job_id", "job_events", ["job_id"])


def downgrade() -> None:
    op.drop_table("job_events")
    op.drop_table("job_results")
    op.drop_table("jobs")
