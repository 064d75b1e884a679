"""A plan job planned below the site's safety floor is a comparison (never approved or dispatched).

Revision ID: 0003
Revises: 0002
"""

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("comparison", sa.Boolean))


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("comparison")
