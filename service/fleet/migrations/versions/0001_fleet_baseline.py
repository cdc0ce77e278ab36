"""The shore's first schema: units, one table per kind of vessel row, the ingest log.

Revision ID: 0001
Revises:
Create Date: 2026-11-27
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import JSONB

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BIG_ID = sa.BigInteger().with_variant(sa.Integer(), "sqlite")  # SQLite: an alias of ROWID
DOCUMENT = sa.JSON().with_variant(JSONB(), "postgresql")
TIME = sa.DateTime(timezone=True)


def _kind_table(name: str, *extra: sa.Column) -> None:
    op.create_table(
        name,
        sa.Column("id", BIG_ID, primary_key=True),
        sa.Column(
            "unit_id",
            sa.Integer(),
            sa.ForeignKey("fleet_units.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column("vessel_id", sa.BigInteger(), nullable=False),
        sa.Column("at", TIME, nullable=False),
        sa.Column("received_at", TIME, nullable=False),
        sa.Column("data", DOCUMENT, nullable=False),
        *extra,
        sa.UniqueConstraint("unit_id", "vessel_id", name=f"uq_{name}_key"),
    )
    op.create_index(f"ix_{name}_unit_at", name, ["unit_id", "at"])


def upgrade() -> None:
    op.create_table(
        "fleet_units",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("serial", sa.String(64), nullable=False, unique=True),
        sa.Column("model", sa.String(64), nullable=True),
        sa.Column("token_hash", sa.String(64), nullable=False, unique=True),
        sa.Column("created_at", TIME, nullable=False),
        sa.Column("last_contact", TIME, nullable=True),
    )
    for name in ("fleet_sessions", "fleet_windows", "fleet_slews"):
        _kind_table(name)
    _kind_table(
        "fleet_versions",
        sa.Column("accepted", sa.Boolean(), nullable=False),
        sa.Column("trigger", sa.String(64), nullable=True),
        sa.Column("method", sa.String(64), nullable=True),
    )
    op.create_index("ix_fleet_versions_accepted_at", "fleet_versions", ["accepted", "at"])
    _kind_table("fleet_events", sa.Column("kind", sa.String(64), nullable=False))
    op.create_index("ix_fleet_events_kind_at", "fleet_events", ["kind", "at"])
    op.create_table(
        "fleet_ingest_log",
        sa.Column("id", BIG_ID, primary_key=True),
        sa.Column(
            "unit_id",
            sa.Integer(),
            sa.ForeignKey("fleet_units.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column("at", TIME, nullable=False),
        sa.Column("compressed_bytes", sa.Integer(), nullable=False),
        sa.Column("rows", sa.Integer(), nullable=False),
        sa.Column("stored", sa.Integer(), nullable=False),
    )
    op.create_index("ix_fleet_ingest_log_unit_at", "fleet_ingest_log", ["unit_id", "at"])


def downgrade() -> None:
    for name in ("fleet_ingest_log", "fleet_events", "fleet_versions", "fleet_slews",
                 "fleet_windows", "fleet_sessions", "fleet_units"):  # fmt: skip
        op.drop_table(name)
