"""Each version's coefficients and 1-sigma by flat name, kept beside its document (issue 28).

The fleet prior read every accepted version's document (about 30 kB of JSON, TOAST-compressed)
to pull out its coefficients and 1-sigma: 10.7 s for 200 units x 5 years at each new accepted
version (docs/fleet.md#scale). Ingest now keeps what the prior reads
(:func:`recal.fleet.history.flat_version` by the conventions' flat names, about 2 kB) in
``fleet_versions.flat``; the rows already stored are filled in here, a batch of rows at a time.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-27
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import JSONB

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: Rows read and updated at a time (their documents decoded in Python).
BATCH = 500


def upgrade() -> None:
    from recal.fleet.history import flat_version
    from service.fleet.priors import coefficient_names

    json_type = sa.JSON().with_variant(JSONB(), "postgresql")
    op.add_column("fleet_versions", sa.Column("flat", json_type, nullable=True))
    names = coefficient_names()
    versions = sa.table("fleet_versions", sa.column("id", sa.BigInteger()),
                        sa.column("data", json_type), sa.column("flat", json_type))  # fmt: skip
    doc = versions.c.data["document"]
    conn = op.get_bind()
    last = None
    while True:
        query = sa.select(versions.c.id, doc["coefficients"], doc["uncertainty"])
        query = query.order_by(versions.c.id)
        if last is not None:
            query = query.where(versions.c.id > last)
        found = conn.execute(query.limit(BATCH)).all()
        if not found:
            break
        conn.execute(
            sa.update(versions).where(versions.c.id == sa.bindparam("row_id")),
            [{"row_id": row_id, "flat": flat_version({"coefficients": _json(c),
                                                      "uncertainty": _json(u)}, names)}
             for row_id, c, u in found],
        )  # fmt: skip
        last = found[-1][0]


def _json(value: Any) -> Any:
    """A JSON value selected out of a document (SQLite may hand it back as text)."""
    if isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return None
    return value


def downgrade() -> None:
    op.execute("ALTER TABLE fleet_versions DROP COLUMN flat")  # SQLite 3.35 and later
