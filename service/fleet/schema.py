"""The shore's tables (SQLAlchemy 2), on their own :class:`FleetBase`, apart from the vessel's.

Every table is named ``fleet_*``, and the migrations keep their revision in
``fleet_alembic_version``, so the shore may share a database with anything else. A vessel row
is stored once per (unit, vessel database instance, vessel row id): one table per kind, each
with that unique key, the row's time (``at``), the vessel's document as JSON (``data``), a
digest of its content (``digest``) and the columns the fleet queries filter on pulled out of
it. A row whose key is stored with other content goes to ``fleet_conflicts``, kept whole.
Revisions under ``migrations/versions`` create these tables by hand; the test suite checks
that they match.
"""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    UniqueConstraint,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

#: Serial of a unit: letters, digits and ``.-_``, at most this long.
MAX_SERIAL = 64
#: A vessel database's instance id (a uuid4, 36 characters; "" for the legacy instance).
MAX_INSTANCE = 36


class FleetBase(DeclarativeBase):
    pass


class UnitRow(FleetBase):
    __tablename__ = "fleet_units"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    serial: Mapped[str] = mapped_column(String(MAX_SERIAL), unique=True)
    model: Mapped[str | None] = mapped_column(String(64))
    #: hex sha256 of the unit's token (the token itself is never stored)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    last_contact: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    #: kept by ingest (migration 0003), so the fleet's list reads no vessel rows
    n_versions: Mapped[int] = mapped_column(Integer, server_default="0")
    n_windows: Mapped[int] = mapped_column(BigInteger, server_default="0")
    #: the newest accepted version stored (the latest by its creation time, whichever vessel
    #: database instance made it: a rebuilt vessel's numbers start at 1 again), its instance
    #: and time (migration 0007)
    current_version: Mapped[int | None] = mapped_column(BigInteger)
    current_instance: Mapped[str | None] = mapped_column(String(MAX_INSTANCE))
    current_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    #: the vessel database instance of the latest batch ("" for a vessel that sends none)
    instance: Mapped[str | None] = mapped_column(String(MAX_INSTANCE))
    #: rows kept in fleet_conflicts (a key stored with other content)
    n_conflicts: Mapped[int] = mapped_column(Integer, server_default="0")
    #: the unit's rejected versions, kept by ingest as ``n_versions`` (migration 0008)
    n_rejected: Mapped[int] = mapped_column(Integer, server_default="0")
    #: what the overview shows of the unit, kept by ingest (migration 0009): the shore row ids
    #: of its current version (the newest accepted by time, then vessel row id), its newest
    #: version and newest rejected one, and its newest ``drift`` event; and the backlog its
    #: newest batch reported
    current_row: Mapped[int | None] = mapped_column(BigInteger)
    last_version_row: Mapped[int | None] = mapped_column(BigInteger)
    rejected_row: Mapped[int | None] = mapped_column(BigInteger)
    drift_row: Mapped[int | None] = mapped_column(BigInteger)
    backlog: Mapped[int | None] = mapped_column(Integer)


class _VesselRow:
    """Columns every kind shares: the key (unit, vessel database instance, vessel row id), the
    time, the document and its content digest."""

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    unit_id: Mapped[int] = mapped_column(ForeignKey("fleet_units.id", ondelete="CASCADE"))
    vessel_id: Mapped[int] = mapped_column(BigInteger)
    #: the vessel database that made the row (the batch's ``instance``; "" before there was
    #: one: the legacy instance), migration 0007
    instance: Mapped[str] = mapped_column(String(MAX_INSTANCE), server_default="")
    at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    received_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    data: Mapped[dict] = mapped_column(JSON().with_variant(JSONB, "postgresql"))
    #: service.fleet.batch.content_digest of ``data`` as received (NULL: stored before 0007)
    digest: Mapped[str | None] = mapped_column(String(64))


def _key_and_time(name: str) -> tuple[UniqueConstraint, Index]:
    """The key of a kind's table, and the index of the per-unit time queries: with the vessel
    row id, so where a time range starts in id order is an index-only scan (migration 0004).
    The key's columns go (unit, vessel row id, instance): a unit's rows in vessel row id order
    (the REST pages) are a walk of the key's index, whatever the instances (migration 0007)."""
    return (
        UniqueConstraint("unit_id", "vessel_id", "instance", name=f"uq_{name}_key"),
        Index(f"ix_{name}_unit_at_id", "unit_id", "at", "vessel_id"),
    )


class SessionRow(_VesselRow, FleetBase):
    __tablename__ = "fleet_sessions"
    __table_args__ = _key_and_time(__tablename__)


class WindowRow(_VesselRow, FleetBase):
    __tablename__ = "fleet_windows"
    __table_args__ = _key_and_time(__tablename__)


class SlewRow(_VesselRow, FleetBase):
    __tablename__ = "fleet_slews"
    __table_args__ = _key_and_time(__tablename__)


class VersionRow(_VesselRow, FleetBase):
    """A calibration version; ``vessel_id`` is the vessel's version number, ``at`` its
    ``created_at``."""

    __tablename__ = "fleet_versions"
    __table_args__ = (
        *_key_and_time(__tablename__),
        Index("ix_fleet_versions_accepted_at", "accepted", "at"),
        # each unit's accepted versions counted, and their newest, without reading the wide
        # rows (the fleet prior's inputs, read by every overview), migration 0008
        Index("ix_fleet_versions_unit_accepted_id", "unit_id", "accepted", "id"),
    )

    accepted: Mapped[bool] = mapped_column(Boolean)
    trigger: Mapped[str | None] = mapped_column(String(64))
    method: Mapped[str | None] = mapped_column(String(64))
    #: what the fleet prior reads of the document (recal.fleet.history.flat_version by the
    #: conventions' flat names, about 2 kB), kept at ingest (migration 0006)
    flat: Mapped[dict | None] = mapped_column(JSON().with_variant(JSONB, "postgresql"))
    #: what the overview shows of the document, kept at ingest (migration 0008): its
    #: ``navigation.after.heading_error_deg_rms`` (a number) and ``reasons`` (a list)
    heading_error_deg_rms: Mapped[float | None] = mapped_column(Float)
    reasons: Mapped[list | None] = mapped_column(JSON().with_variant(JSONB, "postgresql"))


class EventRow(_VesselRow, FleetBase):
    __tablename__ = "fleet_events"
    __table_args__ = (
        *_key_and_time(__tablename__),
        Index("ix_fleet_events_kind_at", "kind", "at"),
        # a unit's latest event of a kind by time (the overview's drift state), migrations
        # 0002 and 0007 (by time, not vessel row id: a rebuilt vessel's ids start again)
        Index("ix_fleet_events_unit_kind", "unit_id", "kind", "at", "vessel_id"),
    )

    kind: Mapped[str] = mapped_column(String(64))


class IngestRow(FleetBase):
    """One acknowledged batch: what the link carried (bytes per day) and what it stored."""

    __tablename__ = "fleet_ingest_log"
    __table_args__ = (
        Index("ix_fleet_ingest_log_unit_at", "unit_id", "at"),
        # the fleet's last days of traffic (the overview's link), migration 0005
        Index("ix_fleet_ingest_log_at", "at"),
    )

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    unit_id: Mapped[int] = mapped_column(ForeignKey("fleet_units.id", ondelete="CASCADE"))
    at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    compressed_bytes: Mapped[int] = mapped_column(Integer)
    rows: Mapped[int] = mapped_column(Integer)
    stored: Mapped[int] = mapped_column(Integer)
    #: outbox rows the vessel still held besides this batch, when the batch said (0002)
    backlog: Mapped[int | None] = mapped_column(Integer)


class LinkDayRow(FleetBase):
    """A unit's traffic of one UTC day, summed by ingest from the batches it acknowledges (the
    ingest log's per-day totals, kept so the overview's link reads 7 rows a unit, not 42
    batches; migration 0009)."""

    __tablename__ = "fleet_link_days"
    __table_args__ = (Index("ix_fleet_link_days_day", "day"),)

    unit_id: Mapped[int] = mapped_column(
        ForeignKey("fleet_units.id", ondelete="CASCADE"), primary_key=True
    )
    #: the UTC day, ``YYYY-MM-DD``
    day: Mapped[str] = mapped_column(String(10), primary_key=True)
    batches: Mapped[int] = mapped_column(Integer)
    rows: Mapped[int] = mapped_column(BigInteger)
    stored: Mapped[int] = mapped_column(BigInteger)
    compressed_bytes: Mapped[int] = mapped_column(BigInteger)


class ConflictRow(FleetBase):
    """A row received whose key (unit, kind, instance, vessel row id) was stored with other
    content: kept whole, as received, never merged (migration 0007). Once per content: a retry
    of the same batch adds nothing."""

    __tablename__ = "fleet_conflicts"
    __table_args__ = (
        UniqueConstraint(
            "unit_id", "kind", "instance", "vessel_id", "digest", name="uq_fleet_conflicts_key"
        ),  # fmt: skip
        Index("ix_fleet_conflicts_unit_received", "unit_id", "received_at"),
    )

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    unit_id: Mapped[int] = mapped_column(ForeignKey("fleet_units.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(16))
    instance: Mapped[str] = mapped_column(String(MAX_INSTANCE))
    vessel_id: Mapped[int] = mapped_column(BigInteger)
    at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    received_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    digest: Mapped[str] = mapped_column(String(64))
    #: the digest of the row stored under that key (what it differs from)
    stored_digest: Mapped[str] = mapped_column(String(64))
    data: Mapped[dict] = mapped_column(JSON().with_variant(JSONB, "postgresql"))


class PriorRow(FleetBase):
    """A fleet prior computed for a model (``recal.fleet_prior/1`` in ``document``); a new
    ``version`` only when ``inputs`` (a digest of the accepted versions behind it) changed."""

    __tablename__ = "fleet_priors"
    __table_args__ = (UniqueConstraint("model", "version", name="uq_fleet_priors_model_version"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    model: Mapped[str] = mapped_column(String(64))
    version: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    inputs: Mapped[str] = mapped_column(String(64))
    document: Mapped[dict] = mapped_column(JSON().with_variant(JSONB, "postgresql"))


#: The table of each kind of the wire format (docs/fleet.md).
KINDS: dict[str, type[_VesselRow]] = {
    "session": SessionRow,
    "window": WindowRow,
    "slew": SlewRow,
    "version": VersionRow,
    "event": EventRow,
}
