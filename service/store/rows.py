"""The ORM rows: one class per table, as the migrations (service/migrations) make them.

A row class changes only together with a new migration revision;
tests/service/test_migrations.py checks that the migrated schema equals these models.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import JSON, BigInteger, DateTime, Double, ForeignKey, LargeBinary, String, Text
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from recal.model.positions import CANONICAL_ORDER, SHIP_COLUMNS
from service.store.records import utc_now

#: Positions columns stored as real columns (docs/reference.md#positions, schema version 1); the
#: ship's columns (SHIP_COLUMNS, schema version 5) are real columns too, read apart (a database
#: not yet upgraded lacks them); others, the optional ``*_sem`` columns included, go to ``extra``.
POSITION_COLUMNS: tuple[str, ...] = tuple(c for c in CANONICAL_ORDER if not c.endswith("_sem"))


class Base(DeclarativeBase):
    type_annotation_map = {
        float: Double(),
        datetime: DateTime(timezone=True),
        dict[str, Any]: JSON(),
        list[Any]: JSON(),
    }


class SchemaVersionRow(Base):
    __tablename__ = "schema_version"

    version: Mapped[int] = mapped_column(primary_key=True, autoincrement=False)
    applied_at: Mapped[datetime] = mapped_column(default=utc_now)


class SessionRow(Base):
    """An acquisition session (a port, a replayed capture, a simulation)."""

    __tablename__ = "sessions"

    id: Mapped[int] = mapped_column(primary_key=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    source: Mapped[str] = mapped_column(Text)
    meta: Mapped[dict[str, Any]] = mapped_column(default=dict)


class PositionRow(Base):
    """One static window (docs/reference.md#positions); NULL where the column was absent."""

    __tablename__ = "positions"

    id: Mapped[int] = mapped_column(primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id"), index=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    start_s: Mapped[float | None]
    end_s: Mapped[float | None]
    samples: Mapped[float | None]
    gyro_x: Mapped[float | None]
    gyro_y: Mapped[float | None]
    gyro_z: Mapped[float | None]
    accel_x: Mapped[float | None]
    accel_y: Mapped[float | None]
    accel_z: Mapped[float | None]
    temperature_c: Mapped[float | None]
    temperature_rate_c_per_h: Mapped[float | None]
    gyro_x_std: Mapped[float | None]
    gyro_y_std: Mapped[float | None]
    gyro_z_std: Mapped[float | None]
    accel_x_std: Mapped[float | None]
    accel_y_std: Mapped[float | None]
    accel_z_std: Mapped[float | None]
    extra: Mapped[dict[str, Any]] = mapped_column(default=dict)
    # the ship's state over the window ([nav], NMEA 0183; schema version 5): NULL where unknown.
    # Deferred: loaded only where asked for (undefer), so a database made before revision 0005
    # still reads until it is upgraded
    latitude_deg: Mapped[float | None] = mapped_column(deferred=True)
    sog_kn: Mapped[float | None] = mapped_column(deferred=True)
    heading_deg: Mapped[float | None] = mapped_column(deferred=True)


class CalibrationRow(Base):
    """One calibration; ``id`` is the coefficients' version number."""

    __tablename__ = "calibrations"
    # SQLite would otherwise reuse the largest id after a delete; versions must never repeat.
    __table_args__ = {"sqlite_autoincrement": True}

    id: Mapped[int] = mapped_column(primary_key=True)
    created_at: Mapped[datetime]
    trigger: Mapped[str] = mapped_column(String(32))
    method: Mapped[str] = mapped_column(String(64))
    accepted: Mapped[bool] = mapped_column(index=True)
    reasons: Mapped[list[Any]]
    document: Mapped[dict[str, Any]]
    positions_used: Mapped[list[Any]]
    prior_version: Mapped[int | None] = mapped_column(ForeignKey("calibrations.id"))


class EventRow(Base):
    """A log line worth keeping: a job started, a calibration rejected, a reader error."""

    __tablename__ = "events"

    id: Mapped[int] = mapped_column(primary_key=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    kind: Mapped[str] = mapped_column(String(64), index=True)
    message: Mapped[str] = mapped_column(Text)
    data: Mapped[dict[str, Any] | None]


class NoiseFloorRow(Base):
    """The static detector's noise floor for one device: learned once, refined from windows
    that passed, reused after a restart (a unit restarted at sea may be moving)."""

    __tablename__ = "noise_floors"

    id: Mapped[int] = mapped_column(primary_key=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    device: Mapped[str] = mapped_column(Text, index=True)
    accel: Mapped[float] = mapped_column(Double)
    gyro: Mapped[float] = mapped_column(Double)
    window_samples: Mapped[int]
    source: Mapped[str] = mapped_column(Text)
    windows: Mapped[int] = mapped_column(default=0)


class SlewRow(Base):
    """The motion between two stored windows, reduced to group sums (recal.detect.slew_groups), or the
    reason it was dropped (``dropped``; then ``data`` is NULL). ``data`` holds float64 values:
    the first window's mean gyro output (3), then per group its sample count, S, W and C
    (``groups`` x 10)."""

    __tablename__ = "slews"

    id: Mapped[int] = mapped_column(primary_key=True)
    first_id: Mapped[int] = mapped_column(ForeignKey("positions.id"), index=True)
    second_id: Mapped[int] = mapped_column(ForeignKey("positions.id"), index=True)
    period_s: Mapped[float]
    samples: Mapped[int]
    groups: Mapped[int]
    data: Mapped[bytes | None] = mapped_column(LargeBinary)
    dropped: Mapped[str | None] = mapped_column(String(32))


class SpoolBatchRow(Base):
    """A window batch that came through the durable spool (service/spool.py), by its unique
    key, with the positions it became: stored in the positions' transaction, so replaying a
    batch whose spool file outlived its commit (a kill in between) stores nothing twice."""

    __tablename__ = "spool_batches"

    key: Mapped[str] = mapped_column(String(64), primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id"), index=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    position_ids: Mapped[list[Any]]


class OutboxRow(Base):
    """A stored row still to send to the shore (docs/fleet.md): written in the row's own
    transaction, deleted once the shore acknowledged it (service.store.outbox)."""

    __tablename__ = "outbox"
    # the send order: SQLite must never hand out a sequence number again
    __table_args__ = {"sqlite_autoincrement": True}

    seq: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(String(16))
    ref_id: Mapped[int]
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class SyncDayRow(Base):
    """The link's traffic on one UTC day (``YYYY-MM-DD``): bytes sent (compressed, every
    attempt), rows and batches acknowledged, and when the shore last answered."""

    __tablename__ = "sync_days"

    day: Mapped[str] = mapped_column(String(10), primary_key=True)
    sent_bytes: Mapped[int] = mapped_column(BigInteger)
    rows: Mapped[int]
    batches: Mapped[int]
    last_contact: Mapped[datetime | None]


class InstanceRow(Base):
    """This database's identity (schema version 6): one row, a uuid4 made when the database is
    created (a database made before gets one when migrated). Fleet sync sends it with every
    batch, so the shore tells a rebuilt vessel's rows (its ids restart at 1) from the rows of
    the database it replaced (docs/fleet.md)."""

    __tablename__ = "store_instance"

    instance: Mapped[str] = mapped_column(String(36), primary_key=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


_missing = {*POSITION_COLUMNS, *SHIP_COLUMNS} - set(PositionRow.__table__.columns.keys())
assert not _missing, f"PositionRow lacks positions-file columns {_missing}"
