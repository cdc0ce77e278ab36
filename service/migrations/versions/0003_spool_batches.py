"""Table spool_batches: the durable spool's batch keys, unique (schema version 3).

A window batch is deleted from the spool (service/spool.py) only after the database committed
it; its key, stored in the same transaction as its positions, makes a replay after a kill
between the two a no-op.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-25
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

VERSION = 3
schema_version = sa.table(
    "schema_version",
    sa.column("version", sa.Integer()),
    sa.column("applied_at", sa.DateTime(timezone=True)),
)


def upgrade() -> None:
    op.create_table(
        "spool_batches",
        sa.Column("key", sa.String(64), primary_key=True),
        sa.Column("session_id", sa.Integer(), sa.ForeignKey("sessions.id"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("position_ids", sa.JSON(), nullable=False),
    )
    op.create_index("ix_spool_batches_session_id", "spool_batches", ["session_id"])
    # the releases before refuse the database from now on
    op.bulk_insert(schema_version, [{"version": VERSION, "applied_at": datetime.now(UTC)}])


def downgrade() -> None:
    op.execute(schema_version.delete().where(schema_version.c.version == VERSION))
    op.drop_table("spool_batches")
