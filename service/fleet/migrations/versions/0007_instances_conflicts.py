"""Vessel database instances and conflicts (issue 37): no row is dropped silently.

The shore stored a vessel row once per (unit, vessel row id) and took any row whose key it
had for a retry. A vessel whose database is deleted and made again starts its row ids at 1
again, so every row it made afterwards was dropped as a "duplicate". Batches now carry the
vessel database's ``instance`` (a uuid4; none: the legacy instance ""), and:

* each kind's table gets ``instance`` (existing rows: "") and ``digest`` (the content digest
  ingest compares; NULL for rows stored before, whose content is compared as it is stored),
  and its key becomes (unit, vessel row id, instance);
* the index of a unit's latest event of a kind orders by time (a rebuilt vessel's ids restart);
* the unit's row gets the instance of its latest batch, the time and instance of its current
  version (the newest accepted version by creation time, recomputed here) and a count of
  conflicts;
* ``fleet_conflicts`` keeps whole every row received whose key was stored with other content.

On SQLite the kind tables are copied once (a unique constraint cannot be changed in place).

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-02
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import JSONB

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

TABLES = ("fleet_sessions", "fleet_windows", "fleet_slews", "fleet_versions", "fleet_events")
BIG_ID = sa.BigInteger().with_variant(sa.Integer(), "sqlite")
DOCUMENT = sa.JSON().with_variant(JSONB(), "postgresql")
TIME = sa.DateTime(timezone=True)
#: The newest accepted version of a unit by creation time (ties: the higher number).
NEWEST = (
    "FROM fleet_versions v WHERE v.unit_id = fleet_units.id AND v.accepted "
    "ORDER BY v.at DESC, v.vessel_id DESC LIMIT 1"
)


def upgrade() -> None:
    for name in TABLES:
        with op.batch_alter_table(name) as batch:
            batch.add_column(
                sa.Column("instance", sa.String(36), nullable=False, server_default="")
            )
            batch.add_column(sa.Column("digest", sa.String(64), nullable=True))
            batch.drop_constraint(f"uq_{name}_key", type_="unique")
            batch.create_unique_constraint(f"uq_{name}_key", ["unit_id", "vessel_id", "instance"])
    op.drop_index("ix_fleet_events_unit_kind", table_name="fleet_events")
    op.create_index("ix_fleet_events_unit_kind", "fleet_events",
                    ["unit_id", "kind", "at", "vessel_id"])  # fmt: skip
    # plain ALTER TABLE on fleet_units (no batch copy on SQLite: dropping it would cascade)
    op.add_column("fleet_units", sa.Column("current_instance", sa.String(36), nullable=True))
    op.add_column("fleet_units", sa.Column("current_at", TIME, nullable=True))
    op.add_column("fleet_units", sa.Column("instance", sa.String(36), nullable=True))
    op.add_column("fleet_units",
                  sa.Column("n_conflicts", sa.Integer(), nullable=False, server_default="0"))  # fmt: skip
    op.execute(
        "UPDATE fleet_units SET "
        f"current_version = (SELECT v.vessel_id {NEWEST}), "
        f"current_at = (SELECT v.at {NEWEST}), "
        f"current_instance = (SELECT v.instance {NEWEST}), "
        "instance = CASE WHEN last_contact IS NULL THEN NULL ELSE '' END"
    )
    op.create_table(
        "fleet_conflicts",
        sa.Column("id", BIG_ID, primary_key=True),
        sa.Column(
            "unit_id",
            sa.Integer(),
            sa.ForeignKey("fleet_units.id", ondelete="CASCADE"),
            nullable=False,
        ),  # fmt: skip
        sa.Column("kind", sa.String(16), nullable=False),
        sa.Column("instance", sa.String(36), nullable=False),
        sa.Column("vessel_id", sa.BigInteger(), nullable=False),
        sa.Column("at", TIME, nullable=False),
        sa.Column("received_at", TIME, nullable=False),
        sa.Column("digest", sa.String(64), nullable=False),
        sa.Column("stored_digest", sa.String(64), nullable=False),
        sa.Column("data", DOCUMENT, nullable=False),
        sa.UniqueConstraint(
            "unit_id", "kind", "instance", "vessel_id", "digest", name="uq_fleet_conflicts_key"
        ),  # fmt: skip
    )
    op.create_index("ix_fleet_conflicts_unit_received", "fleet_conflicts",
                    ["unit_id", "received_at"])  # fmt: skip


def downgrade() -> None:
    """Back to one row per (unit, vessel row id): the rows of instances other than the
    legacy one go (and the conflicts), since their keys may repeat the legacy rows'."""
    op.drop_table("fleet_conflicts")
    for name in ("n_conflicts", "instance", "current_at", "current_instance"):
        op.execute(f"ALTER TABLE fleet_units DROP COLUMN {name}")  # SQLite 3.35 and later
    op.drop_index("ix_fleet_events_unit_kind", table_name="fleet_events")
    op.create_index("ix_fleet_events_unit_kind", "fleet_events", ["unit_id", "kind", "vessel_id"])
    for name in TABLES:
        op.execute(f"DELETE FROM {name} WHERE instance <> ''")  # noqa: S608 - names above
        with op.batch_alter_table(name) as batch:
            batch.drop_constraint(f"uq_{name}_key", type_="unique")
            batch.create_unique_constraint(f"uq_{name}_key", ["unit_id", "vessel_id"])
            batch.drop_column("digest")
            batch.drop_column("instance")
