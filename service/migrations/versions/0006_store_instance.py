"""Table store_instance: the database's identity, a uuid4 (schema version 6, docs/fleet.md).

Fleet sync keys a vessel's rows on the shore by (unit, vessel row id). A vessel whose database
is deleted and made again (a disk swap, a fresh install) starts its row ids at 1 again, and the
shore took every new row for one it already had. Each database now has an instance id, made
here: when the database is created (this revision runs with the others on an empty database)
or, for a database made before, when it is migrated. Every batch carries it in its header.

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-02
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

VERSION = 6
WHEN = sa.DateTime(timezone=True)
schema_version = sa.table(
    "schema_version",
    sa.column("version", sa.Integer()),
    sa.column("applied_at", WHEN),
)


def upgrade() -> None:
    table = op.create_table(
        "store_instance",
        sa.Column("instance", sa.String(36), primary_key=True),
        sa.Column("created_at", WHEN, nullable=False),
    )
    now = datetime.now(UTC)
    op.bulk_insert(table, [{"instance": str(uuid.uuid4()), "created_at": now}])
    # the releases before refuse the database from now on
    op.bulk_insert(schema_version, [{"version": VERSION, "applied_at": now}])


def downgrade() -> None:
    op.execute(schema_version.delete().where(schema_version.c.version == VERSION))
    op.drop_table("store_instance")
