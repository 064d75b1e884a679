"""Each job's planning time and outcome, written by the runner that planned it.

The API's /metrics derives the job-duration histogram and the outcome counters
from these columns, so they cover jobs run by separate `regrasp worker`
processes and survive restarts. Every scrape runs two aggregate queries over
``jobs``; the two indexes cover them, so a scrape reads index entries instead
of whole rows: jobs by (kind, state), and planning time by (kind, outcome) of
the jobs whose planning ended (``planning_outcome IS NOT NULL`` is a range on
the index's first column).

Revision ID: 0002
Revises: 0001
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("planning_s", sa.Float))
        batch.add_column(sa.Column("planning_outcome", sa.String(16)))
    op.create_index("ix_jobs_kind_state", "jobs", ["kind", "state"])
    op.create_index("ix_jobs_planning_stats", "jobs", ["planning_outcome", "kind", "planning_s"])


def downgrade() -> None:
    op.drop_index("ix_jobs_planning_stats", table_name="jobs")
    op.drop_index("ix_jobs_kind_state", table_name="jobs")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("planning_outcome")
        batch.drop_column("planning_s")
