"""The ingest log indexed by time alone (issue 28).

The overview's link (bytes and rows per day of each unit over the last days) reads the whole
fleet's last days of batches; without an index on the time alone that is a scan of the whole
log, one row per batch of every unit since it was commissioned (0.9 s for 200 units x 5 years
at a batch every 4 hours: docs/fleet.md#scale).

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-27
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_index("ix_fleet_ingest_log_at", "fleet_ingest_log", ["at"])


def downgrade() -> None:
    op.drop_index("ix_fleet_ingest_log_at", table_name="fleet_ingest_log")
