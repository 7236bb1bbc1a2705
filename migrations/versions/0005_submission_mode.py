"""submission mode: push (the server calls the policy's URL) or pull (the policy connects out)

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-23
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Every submission before this revision was push mode: the server default fills existing rows.
    with op.batch_alter_table("submissions") as batch:
        batch.add_column(sa.Column("mode", sa.String(length=8), nullable=False, server_default="push"))


def downgrade() -> None:
    with op.batch_alter_table("submissions") as batch:
        batch.drop_column("mode")
