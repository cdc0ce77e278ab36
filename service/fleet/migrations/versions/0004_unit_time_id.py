"""The per-unit time index of each kind's table carries the vessel row id (issue 28).

``GET /fleet/units/{unit}/windows?since=...`` pages in vessel row id order from ``since`` on.
Walking the unit's rows in id order and dropping those before ``since`` read every older row
from the table (0.8 s median for a ``since`` in the middle of 5 years of one unit's windows:
docs/fleet.md#scale). The store now first finds the first id at or after ``since`` with an
index-only scan of (unit, time, vessel row id), then starts the page there. Building these
indexes reads each table once (minutes for a fleet of years); the old (unit, time) indexes go.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-27
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

TABLES = ("fleet_sessions", "fleet_windows", "fleet_slews", "fleet_versions", "fleet_events")


def upgrade() -> None:
    for name in TABLES:
        op.create_index(f"ix_{name}_unit_at_id", name, ["unit_id", "at", "vessel_id"])
        op.drop_index(f"ix_{name}_unit_at", table_name=name)


def downgrade() -> None:
    for name in TABLES:
        op.create_index(f"ix_{name}_unit_at", name, ["unit_id", "at"])
        op.drop_index(f"ix_{name}_unit_at_id", table_name=name)
