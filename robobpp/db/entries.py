"""Stored scoring parts (``runs.entry``) computed for runs that lack a current one: what the migrations that
introduced and changed the stored format run (0010, 0013), in batches, on the connection they are given."""

from __future__ import annotations

import json
from typing import Any

import sqlalchemy as sa

from robobpp.scoring.entries import FORMAT, part_of_run, stored_format

#: Runs read and written at a time.
BATCH = 2000

_RUNS = sa.table(
    "runs",
    sa.column("id", sa.Integer()),
    sa.column("setting", sa.String()),
    sa.column("status", sa.String()),
    sa.column("figures", sa.Text()),
    sa.column("entry", sa.LargeBinary()),
)


def fill_entries(connection: Any, *, missing_only: bool = False) -> int:
    """Compute ``runs.entry`` of every completed run with figures whose part is missing or (unless
    ``missing_only``) of another format than the current one; returns how many were written. A run without
    figures keeps NULL (its boards show its point figures without an interval)."""
    runs = _RUNS
    where = [runs.c.status == "completed", runs.c.figures.is_not(None)]
    if missing_only:
        where.append(runs.c.entry.is_(None))
    done, last = 0, 0
    while True:
        rows = connection.execute(
            sa.select(runs.c.id, runs.c.setting, sa.cast(runs.c.figures, sa.Text()), runs.c.entry)
            .where(runs.c.id > last, *where)
            .order_by(runs.c.id)
            .limit(BATCH)
        ).all()
        if not rows:
            return done
        values = []
        for run_id, setting, figures, entry in rows:
            if entry is not None and stored_format(entry) == FORMAT:
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
