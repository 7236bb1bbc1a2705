"""episodes.enqueued_at (no re-send after a restart); submissions.verifies_id and verification

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-23
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("episodes") as batch:
        batch.add_column(sa.Column("enqueued_at", sa.DateTime(timezone=True), nullable=True))
    with op.batch_alter_table("submissions") as batch:
        batch.add_column(sa.Column("verifies_id", sa.Integer(), nullable=True))
        batch.add_column(sa.Column("verification", sa.JSON(), nullable=True))
        batch.create_index("ix_submissions_verifies_id", ["verifies_id"])


def downgrade() -> None:
    with op.batch_alter_table("submissions") as batch:
        batch.drop_index("ix_submissions_verifies_id")
        batch.drop_column("verification")
        batch.drop_column("verifies_id")
    with op.batch_alter_table("episodes") as batch:
        batch.drop_column("enqueued_at")
