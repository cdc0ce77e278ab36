"""What the overview reads of a unit's versions, kept in narrow columns (issue 37, item 6).

``GET /fleet/overview`` selected two fields out of version documents per unit (the current
version's gyrocompass heading error, the last rejected version's reasons) and counted each
unit's rejected versions: every call decompressed two 30 kB documents per unit, 0.99 s p95 at
1000 units x 5 years (docs/fleet.md#scale). Ingest now keeps them beside the document:

* ``fleet_versions.heading_error_deg_rms``: the document's ``navigation.after`` figure (a JSON
  number; NULL otherwise) and ``fleet_versions.reasons``: its ``reasons`` (a JSON array; NULL
  otherwise);
* ``fleet_units.n_rejected``: the unit's rejected versions, counted as ``n_versions`` is;
* an index of ``fleet_versions`` on (unit, accepted, row id): the fleet prior's inputs (each
  unit's accepted versions counted, and their newest), which every overview checks, read from
  it alone and not from the wide rows (94 ms to 22 ms at 1000 units x 5 years).

The rows already stored are filled in here by the database itself.

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-03
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import JSONB

revision: str = "0008"
down_revision: str | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: The heading error's path in a version's document, and its reasons'.
HEADING = ("document", "navigation", "after", "heading_error_deg_rms")
FILL = {
    "postgresql": (
        "UPDATE fleet_versions SET "
        "heading_error_deg_rms = CASE WHEN jsonb_typeof(data #> '{{{h}}}') = 'number' "
        "THEN (data #>> '{{{h}}}')::double precision END, "
        "reasons = CASE WHEN jsonb_typeof(data -> 'reasons') = 'array' "
        "THEN data -> 'reasons' END"
    ).format(h=",".join(HEADING)),
    "sqlite": (
        "UPDATE fleet_versions SET "
        "heading_error_deg_rms = CASE WHEN json_type(data, '$.{h}') IN ('integer', 'real') "
        "THEN json_extract(data, '$.{h}') END, "
        "reasons = CASE WHEN json_type(data, '$.reasons') = 'array' "
        "THEN json_extract(data, '$.reasons') END"
    ).format(h=".".join(HEADING)),
}


def upgrade() -> None:
    json_type = sa.JSON().with_variant(JSONB(), "postgresql")
    op.add_column("fleet_versions",
                  sa.Column("heading_error_deg_rms", sa.Float(), nullable=True))  # fmt: skip
    op.add_column("fleet_versions", sa.Column("reasons", json_type, nullable=True))
    # plain ALTER TABLE (no batch copy on SQLite: dropping the old table would cascade)
    op.add_column("fleet_units",
                  sa.Column("n_rejected", sa.Integer(), nullable=False, server_default="0"))  # fmt: skip
    op.execute(FILL[op.get_bind().dialect.name])
    op.create_index("ix_fleet_versions_unit_accepted_id", "fleet_versions",
                    ["unit_id", "accepted", "id"])  # fmt: skip
    op.execute(
        "UPDATE fleet_units SET n_rejected = (SELECT count(*) FROM fleet_versions v "
        "WHERE v.unit_id = fleet_units.id AND NOT v.accepted)"
    )


def downgrade() -> None:
    op.drop_index("ix_fleet_versions_unit_accepted_id", table_name="fleet_versions")
    op.execute("ALTER TABLE fleet_units DROP COLUMN n_rejected")  # SQLite 3.35 and later
    op.execute("ALTER TABLE fleet_versions DROP COLUMN reasons")
    op.execute("ALTER TABLE fleet_versions DROP COLUMN heading_error_deg_rms")
