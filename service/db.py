"""The Store: sessions, positions, calibrations and events in SQLite or PostgreSQL.

SQLAlchemy 2 ORM models plus one repository class. Every public write runs in one transaction,
every call opens its own short-lived ORM session, so one :class:`Store` may be shared by threads.
Versions of the coefficients are the calibration row ids (monotonic, never reused).
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sqlalchemy import (
    JSON,
    DateTime,
    Double,
    Engine,
    ForeignKey,
    LargeBinary,
    String,
    Text,
    create_engine,
    event,
    func,
    inspect,
    select,
    text,
)
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, NoSuchModuleError, SQLAlchemyError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker
from sqlalchemy.pool import StaticPool

from recal.model.positions import CANONICAL_ORDER, Positions

#: Schema version this code writes, kept by the migrations (service/migrations: revision 0003
#: records 3); a database with a newer one is refused, and so is one at an Alembic revision
#: this code does not know.
SCHEMA_VERSION = 3
#: Positions columns stored as real columns (docs/reference.md#positions, schema version 1); others,
#: the optional ``*_sem`` columns included, go to ``extra``.
POSITION_COLUMNS: tuple[str, ...] = tuple(c for c in CANONICAL_ORDER if not c.endswith("_sem"))


class StoreError(RuntimeError):
    """The database cannot be opened or used; the message is one line."""


class UnknownSessionError(StoreError):
    """Positions for a session this database does not have (retrying cannot help)."""


# ---- records ----------------------------------------------------------------------------


def utc_now() -> datetime:
    return datetime.now(UTC)


@dataclass(kw_only=True)
class CalibrationRecord:
    """One calibration, accepted or not, as stored and served (construct with keywords).

    ``document`` is the ``recal calibrate --json`` object; ``version`` is None before insert.
    """

    version: int | None = None
    created_at: datetime = field(default_factory=utc_now)
    trigger: str
    method: str
    accepted: bool
    reasons: list[str] = field(default_factory=list)
    document: dict[str, Any]
    positions_used: list[int] = field(default_factory=list)
    prior_version: int | None = None


# ---- ORM models -------------------------------------------------------------------------


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
    """The motion between two stored windows, reduced to group sums (recal.detect.slews), or the
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


_missing = set(POSITION_COLUMNS) - set(PositionRow.__table__.columns.keys())
assert not _missing, f"PositionRow lacks positions-file columns {_missing}"


# ---- JSON ---------------------------------------------------------------------------------


def _plain(obj: Any) -> Any:
    """JSON-ready copy: numpy to Python, NaN/inf to None (PostgreSQL's json rejects NaN)."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | np.ndarray):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, datetime):
        return obj.isoformat()
    return obj


def _dumps(obj: Any) -> str:
    return json.dumps(_plain(obj), allow_nan=False)


def _as_utc(value: datetime) -> datetime:
    """SQLite hands back naive datetimes; everything stored is UTC."""
    return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


def _one_line(exc: BaseException) -> str:
    """First non-empty line of a driver error (psycopg messages span several lines)."""
    orig = getattr(exc, "orig", None) or exc
    lines = [ln.strip() for ln in str(orig).splitlines() if ln.strip()]
    return lines[0] if lines else type(orig).__name__


# ---- the Store ----------------------------------------------------------------------------


class Store:
    """Repository over one database URL (``sqlite:///file.db`` or ``postgresql+psycopg://...``).

    Opening connects once and checks the schema version; :meth:`create_schema` creates or
    upgrades the tables (service/migrations). Database failures surface as :class:`StoreError`.
    """

    def __init__(self, url: str, *, connect_timeout_s: float = 5.0) -> None:
        try:
            parsed = make_url(url)
        except ArgumentError:
            raise StoreError(
                f"bad database URL {url!r}: expected e.g. sqlite:///recal.db or "
                "postgresql+psycopg://user@host:5432/db"
            ) from None
        self.url = parsed.render_as_string(hide_password=True)
        self._lock: AbstractContextManager[Any] = nullcontext()
        try:
            self._engine = self._make_engine(parsed, connect_timeout_s)
        except (NoSuchModuleError, ImportError) as exc:
            raise StoreError(f"cannot use database URL {self.url}: {_one_line(exc)}") from None
        # Writers of a file SQLite database take the write lock up front (see _on_begin).
        self._read = sessionmaker(self._engine, expire_on_commit=False)
        self._write = sessionmaker(
            self._engine.execution_options(recal_write=True), expire_on_commit=False
        )
        try:
            self._check_schema_version()
        except StoreError:
            self._engine.dispose()  # a refused database keeps no pooled connection
            raise

    def _make_engine(self, url: Any, connect_timeout_s: float) -> Engine:
        backend = url.get_backend_name()
        if backend == "sqlite":
            memory = url.database in (None, "", ":memory:")
            args: dict[str, Any] = {"check_same_thread": False, "timeout": 30.0}
            if memory:
                # One shared connection holds the whole database; calls take turns on it.
                self._lock = threading.RLock()
                engine = create_engine(
                    url, connect_args=args, poolclass=StaticPool, json_serializer=_dumps
                )
            else:
                engine = create_engine(url, connect_args=args, json_serializer=_dumps)
            event.listen(engine, "connect", _sqlite_on_connect(wal=not memory))
            event.listen(engine, "begin", _sqlite_on_begin)
            return engine
        args = (
            {"connect_timeout": max(1, round(connect_timeout_s))} if backend == "postgresql" else {}
        )
        return create_engine(url, connect_args=args, pool_pre_ping=True, json_serializer=_dumps)

    def close(self) -> None:
        """Release every pooled connection."""
        self._engine.dispose()

    @property
    def dialect(self) -> str:
        return self._engine.dialect.name

    @contextmanager
    def _tx(self, write: bool = False) -> Iterator[Session]:
        """One ORM session in one transaction: committed on success, rolled back on error."""
        maker = self._write if write else self._read
        with self._lock:
            try:
                with maker.begin() as session:
                    yield session
            except SQLAlchemyError as exc:
                raise StoreError(f"database {self.url}: {_one_line(exc)}") from exc

    # ---- schema -------------------------------------------------------------------------
    def _check_schema_version(self) -> None:
        # SQLite answers "database is locked" at once (no busy wait) when a new connection's
        # WAL set-up meets another process migrating the file: wait for it, as a writer would
        deadline = time.monotonic() + 30.0
        while True:
            try:
                with self._lock, self._engine.connect() as conn:
                    found, revisions = _recorded_schema(conn)
                break
            except SQLAlchemyError as exc:
                line = _one_line(exc)
                if "locked" in line and time.monotonic() < deadline:
                    time.sleep(0.05)
                    continue
                raise StoreError(f"cannot open database {self.url}: {line}") from None
        _require_known(found, revisions, self.url)

    def create_schema(self) -> None:
        """Bring the schema to this code's version with the migrations (idempotent).

        An empty database runs them all; one made by the release before migrations (an integer
        ``schema_version``, no ``alembic_version``) is stamped with the revision it matches,
        then upgraded; a migrated one is upgraded to the head (nothing to do when current).
        Everything runs in one transaction; a newer database is refused.
        """
        from alembic import command
        from alembic.util import CommandError

        from service.migrations import LEGACY_REVISIONS, alembic_config

        try:
            with (
                self._lock,
                self._engine.execution_options(recal_write=True).connect() as conn,
                conn.begin(),
            ):
                if self.dialect == "postgresql":  # two processes starting at once: one migrates
                    conn.execute(text("SELECT pg_advisory_xact_lock(7310599)"))
                found, revisions = _recorded_schema(conn)
                _require_known(found, revisions, self.url)
                cfg = alembic_config(conn)
                if found is not None and not revisions:
                    if found not in LEGACY_REVISIONS:
                        raise StoreError(
                            f"database {self.url} has schema version {found} but no migration "
                            "record (table alembic_version): cannot upgrade it"
                        )
                    command.stamp(cfg, LEGACY_REVISIONS[found])
                command.upgrade(cfg, "head")
        except SQLAlchemyError as exc:
            raise StoreError(f"database {self.url}: {_one_line(exc)}") from exc
        except CommandError as exc:
            raise StoreError(f"database {self.url}: migration failed: {_one_line(exc)}") from exc

    def schema_version(self) -> int | None:
        """The integer schema version recorded (None before :meth:`create_schema`)."""
        with self._tx() as s:
            return s.scalar(select(func.max(SchemaVersionRow.version)))

    def schema_revision(self) -> str | None:
        """The Alembic revision recorded (None for an empty or pre-migration database)."""
        return self.recorded_schema()[1]

    def recorded_schema(self) -> tuple[int | None, str | None]:
        """The integer schema version and the Alembic revision recorded, None where absent
        (both for an empty database; no revision for one made before migrations)."""
        try:
            with self._lock, self._engine.connect() as conn:
                found, revisions = _recorded_schema(conn)
        except SQLAlchemyError as exc:
            raise StoreError(f"database {self.url}: {_one_line(exc)}") from exc
        return found, ",".join(revisions) or None

    # ---- sessions and positions ---------------------------------------------------------
    def add_session(self, source: str, meta: Mapping[str, Any] | None = None) -> int:
        """Record an acquisition session; returns its id."""
        with self._tx(write=True) as s:
            row = SessionRow(source=source, meta=dict(meta or {}))
            s.add(row)
            s.flush()
            return row.id

    def add_positions(
        self,
        session_id: int,
        columns: Mapping[str, ArrayLike],
        slews: Sequence[tuple[int, int, Any]] = (),
        period_s: float | None = None,
        previous_id: int | None = None,
        spool_key: str | None = None,
    ) -> list[int]:
        """Store positions (name -> (M,) array, docs/reference.md#positions); returns their ids.

        The columns are validated as a :class:`Positions` first (RecalInputError if bad).
        ``slews``: ``(first row, second row, recal.detect.slews.ReducedSlew)`` between these windows,
        stored in the same transaction; row -1 is the window stored before, ``previous_id``
        (a slew whose first window is unknown is skipped). ``period_s``: gyro sample period.
        ``spool_key``: the batch's spool key; when positions with it are already stored (a
        replay after a kill between commit and spool delete) nothing is added and their ids are
        returned.
        """
        table = Positions.from_columns(columns, source=f"positions for session {session_id}")
        known = [c for c in POSITION_COLUMNS if c in table.columns]
        extra = [c for c in table.columns if c not in POSITION_COLUMNS]
        rows = [
            PositionRow(
                session_id=session_id,
                **{c: float(table.columns[c][i]) for c in known},
                extra={c: _finite_or_none(table.columns[c][i]) for c in extra},
            )
            for i in range(len(table))
        ]
        with self._tx(write=True) as s:
            if s.get(SessionRow, session_id) is None:
                raise UnknownSessionError(f"database {self.url}: unknown session {session_id}")
            if spool_key is not None and (done := _keyed(s, spool_key)):
                return done  # stored before the spool could delete it: nothing twice
            s.add_all(rows)
            s.flush()
            ids = [r.id for r in rows]
            s.add_all(_slew_rows(slews, ids, previous_id, period_s))
            if spool_key is not None:  # unique: a concurrent replay of it fails and rolls back
                s.add(SpoolBatchRow(key=spool_key, session_id=session_id, position_ids=ids))
            return ids

    def keyed_positions(self, spool_key: str) -> list[int]:
        """The ids of the positions stored with this spool key (empty: not stored)."""
        with self._tx() as s:
            return _keyed(s, spool_key)

    def slews(self, ids: Sequence[int]) -> list[SlewRecord]:
        """The stored slews between positions of ``ids`` (both ends in it), in id order."""
        wanted = set(ids)
        if not wanted:
            return []
        lo, hi = min(wanted), max(wanted)
        query = (
            select(SlewRow)
            .where(SlewRow.first_id >= lo, SlewRow.second_id <= hi)
            .order_by(SlewRow.id)
        )
        with self._tx() as s:
            rows = list(s.scalars(query))
        return [_slew_record(r) for r in rows if r.first_id in wanted and r.second_id in wanted]

    def positions(
        self,
        session_id: int | None = None,
        since_id: int | None = None,
        limit: int | None = None,
    ) -> tuple[Positions, list[int]]:
        """Positions in id order (the first ``limit`` after ``since_id``) and their ids.

        Only columns present in every returned row are included; an empty result is an
        empty :class:`Positions`.
        """
        query = select(PositionRow).order_by(PositionRow.id)
        if session_id is not None:
            query = query.where(PositionRow.session_id == session_id)
        if since_id is not None:
            query = query.where(PositionRow.id > since_id)
        if limit is not None:
            query = query.limit(limit)
        with self._tx() as s:
            rows = list(s.scalars(query))
        ids = [r.id for r in rows]
        source = f"store {self.url}" + (f" positions {ids[0]}..{ids[-1]}" if ids else "")
        return Positions(columns=_columns_of(rows), source=source), ids

    def count_positions(self, session_id: int | None = None, since_id: int | None = None) -> int:
        """Stored positions (of one session; with ids after ``since_id``)."""
        query = select(func.count(PositionRow.id))
        if session_id is not None:
            query = query.where(PositionRow.session_id == session_id)
        if since_id is not None:
            query = query.where(PositionRow.id > since_id)
        with self._tx() as s:
            return int(s.scalar(query) or 0)

    def sessions_of(self, ids: Sequence[int]) -> np.ndarray:
        """(M,) the session id of each stored window in ``ids`` (in that order): each session
        restarts the device clock, so window times compare only within one."""
        if not ids:
            return np.zeros(0)
        query = select(PositionRow.id, PositionRow.session_id).where(PositionRow.id.in_(list(ids)))
        with self._tx() as s:
            found = dict(s.execute(query).all())
        return np.array([float(found[i]) for i in ids])

    def window_rate(self) -> tuple[int, float]:
        """Stored windows and the device time they were found in, s: per session, from the
        first window's start to the last one's end (sessions restart the device clock)."""
        query = select(
            func.count(PositionRow.id), func.min(PositionRow.start_s), func.max(PositionRow.end_s)
        ).group_by(PositionRow.session_id)
        count, span = 0, 0.0
        with self._tx() as s:
            for n, first, last in s.execute(query):
                count += int(n or 0)
                if first is not None and last is not None and last > first:
                    span += float(last) - float(first)
        return count, span

    # ---- calibrations -------------------------------------------------------------------
    def add_calibration(self, record: CalibrationRecord) -> int:
        """Store a calibration (accepted or not); returns its version number."""
        row = CalibrationRow(
            created_at=_as_utc(record.created_at),
            trigger=record.trigger,
            method=record.method,
            accepted=bool(record.accepted),
            reasons=[str(r) for r in record.reasons],
            document=record.document,
            positions_used=[int(i) for i in record.positions_used],
            prior_version=record.prior_version,
        )
        with self._tx(write=True) as s:
            s.add(row)
            s.flush()
            return row.id

    def current(self) -> CalibrationRecord | None:
        """The latest accepted calibration."""
        query = (
            select(CalibrationRow)
            .where(CalibrationRow.accepted.is_(True))
            .order_by(CalibrationRow.id.desc())
            .limit(1)
        )
        with self._tx() as s:
            row = s.scalar(query)
            return None if row is None else _record(row)

    def calibration(self, version: int) -> CalibrationRecord | None:
        with self._tx() as s:
            row = s.get(CalibrationRow, version)
            return None if row is None else _record(row)

    def history(self, limit: int = 50) -> list[CalibrationRecord]:
        """Calibrations, accepted or not, newest first."""
        query = select(CalibrationRow).order_by(CalibrationRow.id.desc()).limit(limit)
        with self._tx() as s:
            return [_record(r) for r in s.scalars(query)]

    # ---- events -------------------------------------------------------------------------
    def add_event(self, kind: str, message: str, data: Mapping[str, Any] | None = None) -> int:
        with self._tx(write=True) as s:
            row = EventRow(kind=kind, message=message, data=None if data is None else dict(data))
            s.add(row)
            s.flush()
            return row.id

    def last_event(self, kind: str, **data: Any) -> dict[str, Any] | None:
        """The newest event of ``kind`` whose data holds every ``key=value`` given (or None);
        looks at the last 1000 events of that kind."""
        query = select(EventRow).where(EventRow.kind == kind).order_by(EventRow.id.desc())
        with self._tx() as s:
            for r in s.scalars(query.limit(1000)):
                if all((r.data or {}).get(k) == v for k, v in data.items()):
                    return {"id": r.id, "kind": r.kind, "message": r.message, "data": r.data}
        return None

    # ---- detector noise floor -----------------------------------------------------------
    def save_noise_floor(self, device: str, floor: Mapping[str, Any]) -> int:
        """Record the detector's noise floor for ``device`` (keys accel, gyro, window_samples,
        source, windows); the newest row is the one in force."""
        with self._tx(write=True) as s:
            row = NoiseFloorRow(
                device=device,
                accel=float(floor["accel"]),
                gyro=float(floor["gyro"]),
                window_samples=int(floor["window_samples"]),
                source=str(floor["source"]),
                windows=int(floor.get("windows", 0)),
            )
            s.add(row)
            s.flush()
            return row.id

    def noise_floor(self, device: str) -> dict[str, Any] | None:
        """The newest noise floor stored for ``device``, or None."""
        query = (
            select(NoiseFloorRow)
            .where(NoiseFloorRow.device == device)
            .order_by(NoiseFloorRow.id.desc())
            .limit(1)
        )
        with self._tx() as s:
            r = s.scalar(query)
            if r is None:
                return None
            return {
                "accel": r.accel,
                "gyro": r.gyro,
                "window_samples": r.window_samples,
                "source": r.source,
                "windows": r.windows,
                "created_at": _as_utc(r.created_at).isoformat(),
            }

    def events(self, limit: int = 100) -> list[dict[str, Any]]:
        """Newest first, as JSON-ready dicts (``created_at`` in ISO 8601 UTC)."""
        query = select(EventRow).order_by(EventRow.id.desc()).limit(limit)
        with self._tx() as s:
            return [
                {
                    "id": r.id,
                    "created_at": _as_utc(r.created_at).isoformat(),
                    "kind": r.kind,
                    "message": r.message,
                    "data": r.data,
                }
                for r in s.scalars(query)
            ]

    # ---- paged history summaries (what /coefficients/history lists) ----------------------
    def history_summaries(
        self, limit: int = 50, before_version: int | None = None
    ) -> list[dict[str, Any]]:
        """Calibrations newest first, older than ``before_version`` when given, without their
        documents: version, time, trigger, method, accepted, reasons, prior version and the key
        figures (``positions``, ``chi2_red``, ``verdict``, ``sensor``) read inside the database.
        """
        doc = CalibrationRow.document
        query = (
            select(
                CalibrationRow.id,
                CalibrationRow.created_at,
                CalibrationRow.trigger,
                CalibrationRow.method,
                CalibrationRow.accepted,
                CalibrationRow.reasons,
                CalibrationRow.prior_version,
                func.json_array_length(CalibrationRow.positions_used),
                doc["chi2_red"].as_float(),
                doc[("observability", "verdict")].as_string(),
                doc["sensor"].as_string(),
            )
            .order_by(CalibrationRow.id.desc())
            .limit(limit)
        )
        if before_version is not None:
            query = query.where(CalibrationRow.id < before_version)
        with self._tx() as s:
            rows = s.execute(query).all()
        keys = ("version", "created_at", "trigger", "method", "accepted", "reasons",
                "prior_version", "positions", "chi2_red", "verdict", "sensor")  # fmt: skip
        out = [dict(zip(keys, row, strict=True)) for row in rows]
        for item in out:
            item["created_at"] = _as_utc(item["created_at"])
            item["reasons"] = list(item["reasons"] or [])
        return out


# ---- helpers ------------------------------------------------------------------------------


@dataclass(frozen=True)
class SlewRecord:
    """A stored slew (see :class:`SlewRow`); ``groups`` is None when it was dropped."""

    first_id: int
    second_id: int
    period_s: float
    samples: int
    reference: np.ndarray | None
    groups: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None
    dropped: str | None


def _keyed(s: Session, spool_key: str) -> list[int]:
    row = s.get(SpoolBatchRow, spool_key)
    return [] if row is None else [int(i) for i in row.position_ids]


def _slew_rows(
    slews: Sequence[tuple[int, int, Any]],
    ids: list[int],
    previous_id: int | None,
    period_s: float | None,
) -> list[SlewRow]:
    out = []
    for a, b, r in slews:
        first = previous_id if a < 0 else ids[a]
        if first is None or period_s is None:
            continue
        data = None
        G = 0
        if r.groups is not None:
            counts, S, W, C = r.groups
            G = int(counts.shape[0])
            body = np.column_stack([counts, S, W, C]).astype(np.float64)
            data = np.concatenate([np.asarray(r.reference, np.float64), body.ravel()]).tobytes()
        out.append(SlewRow(first_id=first, second_id=ids[b], period_s=float(period_s),
                           samples=int(r.samples), groups=G, data=data,
                           dropped=r.dropped))  # fmt: skip
    return out


def _slew_record(row: SlewRow) -> SlewRecord:
    ref = groups = None
    if row.data is not None:
        v = np.frombuffer(row.data, dtype=np.float64)
        ref, body = v[:3].copy(), v[3:].reshape(row.groups, 10)
        groups = (body[:, 0].astype(np.int64), body[:, 1:4].copy(), body[:, 4:7].copy(),
                  body[:, 7:10].copy())  # fmt: skip
    return SlewRecord(row.first_id, row.second_id, row.period_s, row.samples, ref, groups,
                      row.dropped)  # fmt: skip


def _recorded_schema(conn: Any) -> tuple[int | None, list[str]]:
    """The integer schema version and the Alembic revisions a database records."""
    tables = set(inspect(conn).get_table_names())
    found = None
    if SchemaVersionRow.__tablename__ in tables:
        found = conn.execute(select(func.max(SchemaVersionRow.version))).scalar()
    revisions = []
    if "alembic_version" in tables:
        revisions = sorted(conn.execute(text("SELECT version_num FROM alembic_version")).scalars())
    return found, revisions


def _require_known(found: int | None, revisions: Sequence[str], url: str) -> None:
    if found is not None and found > SCHEMA_VERSION:
        raise StoreError(
            f"database {url} has schema version {found}, newer than this code knows "
            f"({SCHEMA_VERSION}): upgrade fog-recal"
        )
    if revisions:
        from service.migrations import head
        from service.migrations import revisions as known

        unknown = [r for r in revisions if r not in known()]
        if unknown:
            raise StoreError(
                f"database {url} is at schema revision {', '.join(unknown)}, newer than this "
                f"code knows ({head()}): upgrade fog-recal"
            )


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _columns_of(rows: Sequence[PositionRow]) -> dict[str, np.ndarray]:
    if not rows:
        return {}
    cols: dict[str, np.ndarray] = {}
    for name in POSITION_COLUMNS:
        values = [getattr(r, name) for r in rows]
        if all(v is not None for v in values):
            cols[name] = np.array(values, dtype=float)
    shared = [k for k in rows[0].extra if all(k in r.extra for r in rows)]
    for name in shared:
        cols[name] = np.array(
            [math.nan if r.extra[name] is None else r.extra[name] for r in rows], dtype=float
        )
    return cols


def _record(row: CalibrationRow) -> CalibrationRecord:
    return CalibrationRecord(
        version=row.id,
        created_at=_as_utc(row.created_at),
        trigger=row.trigger,
        method=row.method,
        accepted=row.accepted,
        reasons=list(row.reasons),
        document=row.document,
        positions_used=list(row.positions_used),
        prior_version=row.prior_version,
    )


def _sqlite_on_connect(wal: bool) -> Any:
    def on_connect(dbapi_conn: Any, _record: Any) -> None:
        # Hand transaction control to SQLAlchemy's "begin" event (pysqlite would defer BEGIN).
        dbapi_conn.isolation_level = None
        cursor = dbapi_conn.cursor()
        cursor.execute("PRAGMA foreign_keys=ON")
        if wal:  # readers never block the writer, and the writer never blocks readers
            cursor.execute("PRAGMA journal_mode=WAL")
        cursor.close()

    return on_connect


def _sqlite_on_begin(conn: Any) -> None:
    # IMMEDIATE: a writer waits (busy timeout) for the lock at BEGIN instead of failing later
    # when its read snapshot turns out stale.
    write = conn.get_execution_options().get("recal_write", False)
    conn.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")
