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

import json
import struct
from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0013"
down_revision = "0012"
branch_labels = None
depends_on = None

BATCH = 2000
_FORMAT = struct.Struct("<4sH")  # the part's magic and format


def upgrade() -> None:
    refresh_entries(op.get_bind())


def refresh_entries(connection: Any) -> int:
    """Recompute ``runs.entry`` of every completed run with figures whose part is missing or of another
    format than the current one; returns how many were written."""
    from robobpp.scoring.entries import FORMAT, part_of_run  # the scoring of this revision's code

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
            sa.select(runs.c.id, runs.c.setting, sa.cast(runs.c.figures, sa.Text()), runs.c.entry)
            .where(runs.c.id > last, runs.c.status == "completed", runs.c.figures.is_not(None))
            .order_by(runs.c.id)
            .limit(BATCH)
        ).all()
        if not rows:
            return done
        values = []
        for run_id, setting, figures, entry in rows:
            if entry is not None and len(entry) >= _FORMAT.size and _FORMAT.unpack_from(entry)[1] == FORMAT:
                continue
            part = part_of_run(json.loads(figures) if isinstance(figures, str) else figures, setting)
            if part is not None:
                values.append({"run_id": run_id, "entry": part})
        if values:
            connection.execute(
                runs.update().where(runs.c.id == sa.bindparam("run_id")).values(entry=sa.bindparam("entry")),
                values,
            )
        done += len(values)
        last = rows[-1][0]


def downgrade() -> None:
    """Nothing to undo: an older version recomputes a part of a format it does not know when it reads it."""
