"""board_parts keyed by (track, board, part, version): an entry's row and its older versions side by side

A publication deletes, for each entry row it rewrites, that row's versions older than the one the previous
board version shows (``part = 'e:<id>' AND version < v``). Keyed (track, board, version, part), each such
delete walked every older row of the board: thousands of deletes, each over thousands of index entries, when
a shift rewrote a few thousand rows at 10,000 submissions. Keyed by part first, each is one index probe;
readers look parts up by all four columns, which either order serves.

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-26
"""

from __future__ import annotations

from alembic import op

revision = "0012"
down_revision = "0011"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("board_parts") as batch:  # SQLite: the table is copied with the new key
        batch.drop_constraint("uq_board_parts_key", type_="unique")
        batch.create_unique_constraint("uq_board_parts_key", ["track", "board", "part", "version"])


def downgrade() -> None:
    with op.batch_alter_table("board_parts") as batch:
        batch.drop_constraint("uq_board_parts_key", type_="unique")
        batch.create_unique_constraint("uq_board_parts_key", ["track", "board", "version", "part"])
