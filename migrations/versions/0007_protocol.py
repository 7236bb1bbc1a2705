"""runs.protocol and episodes.protocol (closed loop or the paper's plan-then-replay); episodes.plan

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-26
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Every row stored before is closed loop (the only protocol there was). A submission now has a run and an
    # episode per group under each protocol of a physical setting, so the protocol joins both unique keys, and
    # the boards' index (a board is one dataset × setting × protocol).
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("protocol", sa.String(length=8), nullable=False, server_default="closed"))
        batch.drop_constraint("uq_run", type_="unique")
        batch.create_unique_constraint("uq_run", ["submission_id", "dataset", "setting", "protocol"])
        batch.drop_index("ix_runs_board")
        batch.create_index("ix_runs_board", ["dataset", "setting", "protocol", "status"])
    with op.batch_alter_table("episodes") as batch:
        batch.add_column(sa.Column("protocol", sa.String(length=8), nullable=False, server_default="closed"))
        batch.add_column(sa.Column("plan", sa.JSON(), nullable=True))
        batch.drop_constraint("uq_episode", type_="unique")
        batch.create_unique_constraint(
            "uq_episode", ["submission_id", "dataset", "setting", "group", "protocol"]
        )


def downgrade() -> None:
    # Paper-protocol rows have no place in the old schema (they would break its unique keys): removed.
    op.execute("DELETE FROM episodes WHERE protocol <> 'closed'")
    op.execute("DELETE FROM runs WHERE protocol <> 'closed'")
    op.execute(
        "UPDATE submissions SET episodes_total = "
        "(SELECT count(*) FROM episodes WHERE episodes.submission_id = submissions.id)"
    )
    with op.batch_alter_table("episodes") as batch:
        batch.drop_constraint("uq_episode", type_="unique")
        batch.create_unique_constraint("uq_episode", ["submission_id", "dataset", "setting", "group"])
        batch.drop_column("plan")
        batch.drop_column("protocol")
    with op.batch_alter_table("runs") as batch:
        batch.drop_index("ix_runs_board")
        batch.create_index("ix_runs_board", ["dataset", "setting", "status"])
        batch.drop_constraint("uq_run", type_="unique")
        batch.create_unique_constraint("uq_run", ["submission_id", "dataset", "setting"])
        batch.drop_column("protocol")
