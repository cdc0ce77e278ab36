"""Table slews: the motion between two stored windows, reduced to group sums (schema version 2).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-24
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import context, op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

VERSION = 2
schema_version = sa.table(
    "schema_version",
    sa.column("version", sa.Integer()),
    sa.column("applied_at", sa.DateTime(timezone=True)),
)


def upgrade() -> None:
    if not context.is_offline_mode() and sa.inspect(op.get_bind()).has_table("slews"):
        # made by a build between the release and this revision (create_all): same DDL
        _record_version()
        return
    op.create_table(
        "slews",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("first_id", sa.Integer(), sa.ForeignKey("positions.id"), nullable=False),
        sa.Column("second_id", sa.Integer(), sa.ForeignKey("positions.id"), nullable=False),
        sa.Column("period_s", sa.Double(), nullable=False),
        sa.Column("samples", sa.Integer(), nullable=False),
        sa.Column("groups", sa.Integer(), nullable=False),
        sa.Column("data", sa.LargeBinary(), nullable=True),
        sa.Column("dropped", sa.String(32), nullable=True),
    )
    op.create_index("ix_slews_first_id", "slews", ["first_id"])
    op.create_index("ix_slews_second_id", "slews", ["second_id"])
    _record_version()


def _record_version() -> None:
    # the release before (schema version 1) refuses the database from now on
    op.bulk_insert(schema_version, [{"version": VERSION, "applied_at": datetime.now(UTC)}])


def downgrade() -> None:
    op.execute(schema_version.delete().where(schema_version.c.version == VERSION))
    op.drop_table("slews")
