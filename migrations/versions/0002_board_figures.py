"""per-group run figures for bootstrap intervals; index for the board version check

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-23
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Runs completed before this revision keep figures NULL: their boards show point figures without an
    # interval for them until they are re-evaluated (the episodes are kept, nothing is lost).
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("figures", sa.JSON(), nullable=True))
    op.create_index("ix_submissions_track_finished", "submissions", ["track", "finished_at"])


def downgrade() -> None:
    op.drop_index("ix_submissions_track_finished", table_name="submissions")
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("figures")
