"""Tables outbox and sync_days: fleet sync to the shore (schema version 4, docs/fleet.md).

Every stored session, window, slew, calibration version and event gets an outbox row in its
own transaction from now on; this revision gives the rows already stored theirs, oldest first
(slews at their second window's time), so the history goes to the shore once sync is enabled.
``sync_days`` keeps the link's traffic per UTC day across restarts.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-27
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

VERSION = 4
WHEN = sa.DateTime(timezone=True)
schema_version = sa.table(
    "schema_version",
    sa.column("version", sa.Integer()),
    sa.column("applied_at", WHEN),
)
#: The history already stored, in the order it is sent: by time, then sessions before their
#: windows, windows before their slews, then versions and events; ties by id.
BACKFILL = """
INSERT INTO outbox (kind, ref_id, created_at)
SELECT kind, ref_id, created_at FROM (
    SELECT 'session' AS kind, id AS ref_id, created_at, 0 AS ord FROM sessions
    UNION ALL SELECT 'window', id, created_at, 1 FROM positions
    UNION ALL SELECT 'slew', slews.id, positions.created_at, 2
        FROM slews JOIN positions ON positions.id = slews.second_id
    UNION ALL SELECT 'version', id, created_at, 3 FROM calibrations
    UNION ALL SELECT 'event', id, created_at, 4 FROM events
) AS history
ORDER BY created_at, ord, ref_id
"""


def upgrade() -> None:
    op.create_table(
        "outbox",
        sa.Column("seq", sa.Integer(), primary_key=True),
        sa.Column("kind", sa.String(16), nullable=False),
        sa.Column("ref_id", sa.Integer(), nullable=False),
        sa.Column("created_at", WHEN, nullable=False),
        sqlite_autoincrement=True,  # the send order: SQLite must never reuse a number
    )
    op.create_table(
        "sync_days",
        sa.Column("day", sa.String(10), primary_key=True),
        sa.Column("sent_bytes", sa.BigInteger(), nullable=False),
        sa.Column("rows", sa.Integer(), nullable=False),
        sa.Column("batches", sa.Integer(), nullable=False),
        sa.Column("last_contact", WHEN, nullable=True),
    )
    op.execute(sa.text(BACKFILL))
    # the releases before refuse the database from now on
    op.bulk_insert(schema_version, [{"version": VERSION, "applied_at": datetime.now(UTC)}])


def downgrade() -> None:
    op.execute(schema_version.delete().where(schema_version.c.version == VERSION))
    op.drop_table("sync_days")
    op.drop_table("outbox")
