"""runs.entry: every stored scoring part recomputed in the current format (per-group figures as float32)

Parts are computed once, when a run finishes (robobpp.scoring.entries). A part of an older format is not
read by the boards: without this revision each board start would recompute every such part from the run's
figures and keep nothing of it (minutes at 100,000 submissions, at every start). Here each is recomputed
from its run's figures, in batches, and stored.

Revision ID: 0013
Revises: 0012
Create Date: 2026-11-29
"""

from __future__ import annotations

from alembic import op

revision = "0013"
down_revision = "0012"
branch_labels = None
depends_on = None


def upgrade() -> None:
    from robobpp.db.entries import fill_entries  # the scoring of this revision's code

    fill_entries(op.get_bind())


def downgrade() -> None:
    """Nothing to undo: an older version recomputes a part of a format it does not know when it reads it."""
