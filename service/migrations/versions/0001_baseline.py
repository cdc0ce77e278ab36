"""Baseline: the schema of the last release before migrations (git 612b796, schema version 1).

Revision ID: 0001
Revises:
Create Date: 2026-11-23

Tables schema_version, sessions, positions, calibrations, events, noise_floors, exactly as that
release's ``create_all`` made them. Databases it made are stamped with this revision, not run
through it (``Store.create_schema``).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# What the ORM's annotations map to (service.store.rows.Base.type_annotation_map).
WHEN = sa.DateTime(timezone=True)


def upgrade() -> None:
    version = op.create_table(
        "schema_version",
        sa.Column("version", sa.Integer(), primary_key=True, autoincrement=False),
        sa.Column("applied_at", WHEN, nullable=False),
    )
    op.create_table(
        "sessions",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("created_at", WHEN, nullable=False),
        sa.Column("source", sa.Text(), nullable=False),
        sa.Column("meta", sa.JSON(), nullable=False),
    )
    measured = (
        "start_s end_s samples gyro_x gyro_y gyro_z accel_x accel_y accel_z temperature_c "
        "temperature_rate_c_per_h gyro_x_std gyro_y_std gyro_z_std accel_x_std accel_y_std "
        "accel_z_std"
    ).split()
    op.create_table(
        "positions",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("session_id", sa.Integer(), sa.ForeignKey("sessions.id"), nullable=False),
        sa.Column("created_at", WHEN, nullable=False),
        *(sa.Column(name, sa.Double(), nullable=True) for name in measured),
        sa.Column("extra", sa.JSON(), nullable=False),
    )
    op.create_index("ix_positions_session_id", "positions", ["session_id"])
    op.create_table(
        "calibrations",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("created_at", WHEN, nullable=False),
        sa.Column("trigger", sa.String(32), nullable=False),
        sa.Column("method", sa.String(64), nullable=False),
        sa.Column("accepted", sa.Boolean(), nullable=False),
        sa.Column("reasons", sa.JSON(), nullable=False),
        sa.Column("document", sa.JSON(), nullable=False),
        sa.Column("positions_used", sa.JSON(), nullable=False),
        sa.Column("prior_version", sa.Integer(), sa.ForeignKey("calibrations.id"), nullable=True),
        sqlite_autoincrement=True,  # versions are ids: SQLite must never reuse one
    )
    op.create_index("ix_calibrations_accepted", "calibrations", ["accepted"])
    op.create_table(
        "events",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("created_at", WHEN, nullable=False),
        sa.Column("kind", sa.String(64), nullable=False),
        sa.Column("message", sa.Text(), nullable=False),
        sa.Column("data", sa.JSON(), nullable=True),
    )
    op.create_index("ix_events_kind", "events", ["kind"])
    op.create_table(
        "noise_floors",
        sa.Column("id", sa.Integer(), primary_key=True),
        sa.Column("created_at", WHEN, nullable=False),
        sa.Column("device", sa.Text(), nullable=False),
        sa.Column("accel", sa.Double(), nullable=False),
        sa.Column("gyro", sa.Double(), nullable=False),
        sa.Column("window_samples", sa.Integer(), nullable=False),
        sa.Column("source", sa.Text(), nullable=False),
        sa.Column("windows", sa.Integer(), nullable=False),
    )
    op.create_index("ix_noise_floors_device", "noise_floors", ["device"])
    op.bulk_insert(version, [{"version": 1, "applied_at": datetime.now(UTC)}])


def downgrade() -> None:
    for table in ("noise_floors", "events", "calibrations", "positions", "sessions"):
        op.drop_table(table)  # their indexes go with them
    op.drop_table("schema_version")
