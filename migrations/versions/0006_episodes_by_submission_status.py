"""episodes indexed by (submission, status): a page's progress counts read from the index alone

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-25
"""

from __future__ import annotations

from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Replaces the submission_id index (its prefix serves every lookup that one did): counting a listed
    # page's episodes by status no longer visits the 270 rows of each submission (BENCHMARKS.md, "Evaluation server").
    op.create_index("ix_episodes_submission_status", "episodes", ["submission_id", "status"])
    op.drop_index("ix_episodes_submission_id", table_name="episodes")


def downgrade() -> None:
    op.create_index("ix_episodes_submission_id", "episodes", ["submission_id"])
    op.drop_index("ix_episodes_submission_status", table_name="episodes")
