"""Each job's planning time and outcome, written by the runner that planned it.

The API's /metrics derives the job-duration histogram and the outcome counters
from these columns, so they cover jobs run by separate `regrasp worker`
processes and survive restarts.

Revision ID: 0002
Revises: 0001
"""

from alembic import op
import sqlalchemy as sa

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("planning_s", sa.Float))
        batch.add_column(sa.Column("planning_outcome", sa.String(16)))


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("planning_outcome")
        batch.drop_column("planning_s")
