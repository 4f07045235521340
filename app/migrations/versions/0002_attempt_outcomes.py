"""Why attempts ended: lost workers (they spend the retry budget) and service restarts (they don't).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-25
"""
import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Rows from before this revision start at 0: their past attempts cannot be told apart any more.
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("worker_losses", sa.Integer(), nullable=False, server_default="0"))
        batch.add_column(sa.Column("service_restarts", sa.Integer(), nullable=False, server_default="0"))


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("service_restarts")
        batch.drop_column("worker_losses")
