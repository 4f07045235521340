"""Owners and managed API keys: every job records the key that created it; keys live hashed in ``api_keys``.

Rows from before this revision belong to the admin principal (``created_by = 'admin'``): they were made when
any key could see everything, and only an admin may still do so.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-28
"""
import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("created_by", sa.String(64), nullable=False, server_default="admin"))
        batch.add_column(sa.Column("stored_bytes", sa.BigInteger(), nullable=False, server_default="0"))
    # A key's listing and its usage read its own rows only: newest first, or its active ones; an admin's
    # listing reads every row newest first.
    op.create_index("ix_jobs_created_by_created_at", "jobs", ["created_by", "created_at", "id"])
    op.create_index("ix_jobs_created_at", "jobs", ["created_at", "id"])
    op.create_index("ix_jobs_created_by_state", "jobs", ["created_by", "state"])
    op.create_table(
        "api_keys",
        sa.Column("id", sa.String(32), primary_key=True),
        sa.Column("name", sa.String(100), nullable=False),
        sa.Column("role", sa.String(16), nullable=False),
        sa.Column("secret_sha256", sa.String(64), nullable=False),
        sa.Column("quota", sa.JSON(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("expires_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("revoked_at", sa.DateTime(timezone=True), nullable=True),
    )
    op.create_index("ix_api_keys_secret_sha256", "api_keys", ["secret_sha256"], unique=True)
    op.create_index("ix_api_keys_name", "api_keys", ["name"])


def downgrade() -> None:
    op.drop_table("api_keys")
    op.drop_index("ix_jobs_created_by_state", "jobs")
    op.drop_index("ix_jobs_created_at", "jobs")
    op.drop_index("ix_jobs_created_by_created_at", "jobs")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("stored_bytes")
        batch.drop_column("created_by")
