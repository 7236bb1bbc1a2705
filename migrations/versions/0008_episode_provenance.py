"""episodes.provenance: what produced each episode's result (robobpp version and commit, datasets manifest
sha256, Math rules and sampler versions)

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-26
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Nullable: rows stored before provenance existed stay NULL; they ran version 1 of the Math rules and of
    # the sampler (the first versions), so boards keep them.
    with op.batch_alter_table("episodes") as batch:
        batch.add_column(sa.Column("provenance", sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("episodes") as batch:
        batch.drop_column("provenance")
