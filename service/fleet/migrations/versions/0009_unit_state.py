"""What the overview shows of a unit, kept by ingest (issue 37, item 6).

After migration 0008 ``GET /fleet/overview`` still looked up, per unit and call, its current,
newest and newest rejected version and its newest drift event (four ordered index lookups
each), the backlog of its newest batch, and grouped the fleet's last 7 days of batches (42 a
unit): about 90 ms of the database's time at 1000 units x 5 years, and 0.40 s p95 for the
route under load against a 0.3 s target (docs/fleet.md#scale). Ingest knows each of them when
it stores a row, so it keeps them:

* on ``fleet_units``: the shore row ids of the current version (``current_row``: the newest
  accepted by time, then vessel row id, whichever database instance made it), of the newest
  version (``last_version_row``), of the newest rejected one (``rejected_row``) and of the
  newest ``drift`` event (``drift_row``), and the ``backlog`` its newest batch reported;
* ``fleet_link_days``: per unit and UTC day, the batches, rows, rows stored and compressed
  bytes (the ingest log summed), with an index on the day.

The overview then reads the units joined to those rows by primary key, and 7 link rows a unit.
What is stored already is filled in here from the same tables, in the same order.

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-05
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: The newest row of a unit in a table by time, then vessel row id.
NEWEST = (
    "(SELECT r.id FROM {table} r WHERE r.unit_id = fleet_units.id {where} "
    "ORDER BY r.at DESC, r.vessel_id DESC LIMIT 1)"
)
DRIFT = "AND r.kind = 'drift'"
FILL_UNITS = (
    "UPDATE fleet_units SET "
    f"current_row = {NEWEST.format(table='fleet_versions', where='AND r.accepted')}, "
    f"last_version_row = {NEWEST.format(table='fleet_versions', where='')}, "
    f"rejected_row = {NEWEST.format(table='fleet_versions', where='AND NOT r.accepted')}, "
    f"drift_row = {NEWEST.format(table='fleet_events', where=DRIFT)}, "
    "backlog = (SELECT l.backlog FROM fleet_ingest_log l WHERE l.unit_id = fleet_units.id "
    "ORDER BY l.at DESC, l.id DESC LIMIT 1)"
)
DAY = {
    "postgresql": "to_char(timezone('UTC', at), 'YYYY-MM-DD')",
    "sqlite": "strftime('%Y-%m-%d', at)",
}
FILL_DAYS = (
    "INSERT INTO fleet_link_days (unit_id, day, batches, rows, stored, compressed_bytes) "
    "SELECT unit_id, {day}, count(*), sum(rows), sum(stored), sum(compressed_bytes) "
    "FROM fleet_ingest_log GROUP BY unit_id, {day} ORDER BY {day}, unit_id"
)
UNIT_COLUMNS = ("current_row", "last_version_row", "rejected_row", "drift_row")


def upgrade() -> None:
    # plain ALTER TABLE (no batch copy on SQLite: dropping fleet_units would cascade)
    for name in UNIT_COLUMNS:
        op.add_column("fleet_units", sa.Column(name, sa.BigInteger(), nullable=True))
    op.add_column("fleet_units", sa.Column("backlog", sa.Integer(), nullable=True))
    op.create_table(
        "fleet_link_days",
        sa.Column(
            "unit_id",
            sa.Integer(),
            sa.ForeignKey("fleet_units.id", ondelete="CASCADE"),
            primary_key=True,
        ),  # fmt: skip
        sa.Column("day", sa.String(10), primary_key=True),
        sa.Column("batches", sa.Integer(), nullable=False),
        sa.Column("rows", sa.BigInteger(), nullable=False),
        sa.Column("stored", sa.BigInteger(), nullable=False),
        sa.Column("compressed_bytes", sa.BigInteger(), nullable=False),
    )
    op.execute(FILL_UNITS)
    op.execute(FILL_DAYS.format(day=DAY[op.get_bind().dialect.name]))
    op.create_index("ix_fleet_link_days_day", "fleet_link_days", ["day"])


def downgrade() -> None:
    op.drop_index("ix_fleet_link_days_day", table_name="fleet_link_days")
    op.drop_table("fleet_link_days")
    for name in (*UNIT_COLUMNS, "backlog"):
        op.execute(f"ALTER TABLE fleet_units DROP COLUMN {name}")  # SQLite 3.35 and later
