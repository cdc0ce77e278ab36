"""Columns latitude_deg, sog_kn, heading_deg of positions: the ship's state over a window
(schema version 5; docs/reference.md#positions).

Where the ship's sensors (``[nav]``, NMEA 0183) cover a window, the daemon stores the mean
latitude, speed over ground and true heading with it; NULL where they did not (every window
stored before this revision). A value a caller stored under one of these names before, as an
extra column (in ``extra``), moves to its column.

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-01
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import context, op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

VERSION = 5
#: recal.model.positions.SHIP_COLUMNS, as this revision made them.
SHIP_COLUMNS = ("latitude_deg", "sog_kn", "heading_deg")
schema_version = sa.table(
    "schema_version",
    sa.column("version", sa.Integer()),
    sa.column("applied_at", sa.DateTime(timezone=True)),
)


def upgrade() -> None:
    # nullable columns: SQLite adds them in place (ALTER TABLE ADD COLUMN), no table copy
    with op.batch_alter_table("positions") as batch:
        for name in SHIP_COLUMNS:
            batch.add_column(sa.Column(name, sa.Double(), nullable=True))
    if not context.is_offline_mode():
        _move_from_extra()
    # the releases before refuse the database from now on
    op.bulk_insert(schema_version, [{"version": VERSION, "applied_at": datetime.now(UTC)}])


def _move_from_extra() -> None:
    """Values stored under these names in ``extra`` go to their columns (rare: a positions
    file with such extra columns stored through the API or a script)."""
    positions = sa.table(
        "positions",
        sa.column("id", sa.Integer()),
        sa.column("extra", sa.JSON()),
        *(sa.column(name, sa.Double()) for name in SHIP_COLUMNS),
    )
    bind = op.get_bind()
    text = sa.cast(positions.c.extra, sa.Text())
    has = sa.or_(*(text.like(f'%"{name}"%') for name in SHIP_COLUMNS))
    rows = bind.execute(sa.select(positions.c.id, positions.c.extra).where(has)).all()
    for pid, extra in rows:
        extra = dict(extra or {})
        moved = {name: extra.pop(name) for name in SHIP_COLUMNS if name in extra}
        if moved:
            values = {k: (None if v is None else float(v)) for k, v in moved.items()}
            bind.execute(
                positions.update().where(positions.c.id == pid).values(extra=extra, **values)
            )


def downgrade() -> None:
    op.execute(schema_version.delete().where(schema_version.c.version == VERSION))
    with op.batch_alter_table("positions") as batch:
        for name in reversed(SHIP_COLUMNS):
            batch.drop_column(name)
