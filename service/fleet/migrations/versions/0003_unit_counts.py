"""Each unit's counts kept on its row: versions, windows, current version (issue 28).

``GET /fleet/units`` counted every unit's versions and windows at each call: a scan of the
whole of ``fleet_windows``, which grows with the fleet's years (docs/fleet.md#scale). Ingest
now adds what each batch stored to its unit's row, which it updates anyway (``last_contact``,
in the batch's transaction), and the list reads the units' rows alone. The counts of the rows
already stored are filled in here.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-27
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # plain ALTER TABLE (no batch copy on SQLite: dropping the old table would cascade)
    op.add_column("fleet_units",
                  sa.Column("n_versions", sa.Integer(), nullable=False, server_default="0"))  # fmt: skip
    op.add_column("fleet_units",
                  sa.Column("n_windows", sa.BigInteger(), nullable=False, server_default="0"))  # fmt: skip
    op.add_column("fleet_units", sa.Column("current_version", sa.BigInteger(), nullable=True))
    op.execute(
        "UPDATE fleet_units SET "
        "n_versions = (SELECT count(*) FROM fleet_versions v WHERE v.unit_id = fleet_units.id), "
        "n_windows = (SELECT count(*) FROM fleet_windows w WHERE w.unit_id = fleet_units.id), "
        "current_version = (SELECT max(v.vessel_id) FROM fleet_versions v "
        "WHERE v.unit_id = fleet_units.id AND v.accepted)"
    )


def downgrade() -> None:
    for name in ("current_version", "n_windows", "n_versions"):  # SQLite 3.35 and later
        op.execute(f"ALTER TABLE fleet_units DROP COLUMN {name}")
