"""The fleet priors (one row per computed prior of a model), the vessel's backlog in the ingest
log, and the index of a unit's latest event of a kind (the overview's drift state).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-27
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import JSONB

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "fleet_priors",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("model", sa.String(64), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("inputs", sa.String(64), nullable=False),
        sa.Column("document", sa.JSON().with_variant(JSONB(), "postgresql"), nullable=False),
        sa.UniqueConstraint("model", "version", name="uq_fleet_priors_model_version"),
    )
    op.add_column("fleet_ingest_log", sa.Column("backlog", sa.Integer(), nullable=True))
    op.create_index("ix_fleet_events_unit_kind", "fleet_events", ["unit_id", "kind", "vessel_id"])
