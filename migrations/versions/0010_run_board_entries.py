"""runs.entry: each finished run's own part of the board scoring, computed once (robobpp.scoring.entries)

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-26

The runs completed before this revision get theirs here, from their per-group figures, in batches: a
database of 10,000 submissions (147,600 runs) upgrades in the time BENCHMARKS.md records. A run without
figures keeps NULL (its boards show its point figures without an interval, as before).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("entry", sa.LargeBinary(), nullable=True))
    from robobpp.db.entries import fill_entries  # the scoring of this revision's code

    fill_entries(op.get_bind(), missing_only=True)


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("entry")
