"""episodes.physics_version: the physics that produced each episode's result

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Nullable: Math Pack episodes have no physics, and rows stored before versions existed stay NULL (a
    # board of a physical setting then leaves their runs out).
    with op.batch_alter_table("episodes") as batch:
        batch.add_column(sa.Column("physics_version", sa.String(length=32), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("episodes") as batch:
        batch.drop_column("physics_version")
