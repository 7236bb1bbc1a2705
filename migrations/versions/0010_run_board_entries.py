"""runs.entry: each finished run's own part of the board scoring, computed once (robobpp.scoring.entries)

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-26

The runs completed before this revision get theirs here, from their per-group figures, in batches: a
database of 10,000 submissions (147,600 runs) upgrades in the time BENCHMARKS.md records. A run without
figures keeps NULL (its boards show its point figures without an interval, as before).
"""

from __future__ import annotations

import json
from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None

BATCH = 2000


def upgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.add_column(sa.Column("entry", sa.LargeBinary(), nullable=True))
    fill_entries(op.get_bind())


def fill_entries(connection: Any) -> int:
    """Compute ``runs.entry`` of every completed run with figures that has none; returns how many."""
    from robobpp.scoring.entries import part_of_run  # the scoring of this revision's code

    runs = sa.table(
        "runs",
        sa.column("id", sa.Integer()),
        sa.column("setting", sa.String()),
        sa.column("status", sa.String()),
        sa.column("figures", sa.Text()),
        sa.column("entry", sa.LargeBinary()),
    )
    done, last = 0, 0
    while True:
        rows = connection.execute(
            sa.select(runs.c.id, runs.c.setting, sa.cast(runs.c.figures, sa.Text()))
            .where(
                runs.c.id > last,
                runs.c.status == "completed",
                runs.c.figures.is_not(None),
                runs.c.entry.is_(None),
            )
            .order_by(runs.c.id)
            .limit(BATCH)
        ).all()
        if not rows:
            return done
        values = []
        for run_id, setting, figures in rows:
            entry = part_of_run(json.loads(figures) if isinstance(figures, str) else figures, setting)
            if entry is not None:
                values.append({"run_id": run_id, "entry": entry})
        if values:
            connection.execute(
                runs.update().where(runs.c.id == sa.bindparam("run_id")).values(entry=sa.bindparam("entry")),
                values,
            )
        done += len(values)
        last = rows[-1][0]


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("entry")
