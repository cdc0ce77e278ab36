"""The Store: sessions, positions, calibrations and events in SQLite or PostgreSQL.

One repository class over the ORM rows (:mod:`service.store.rows`). Every public write runs in
one transaction, every call opens its own short-lived ORM session, so one :class:`Store` may be
shared by threads. Versions of the coefficients are the calibration row ids (monotonic, never
reused).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sqlalchemy import func, insert, inspect, select
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, NoSuchModuleError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker, undefer

from recal.model.positions import SHIP_COLUMNS, Positions
from service.store import outbox, schema
from service.store.codec import (
    as_utc,
    columns_of,
    finite_or_none,
    record_of,
    slew_record,
    slew_rows,
)
from service.store.engine import WRITE_OPTION, make_engine
from service.store.errors import StoreError, UnknownSessionError, one_line
from service.store.outbox import OutboxEntry
from service.store.records import CalibrationRecord, SlewRecord
from service.store.rows import (
    POSITION_COLUMNS,
    CalibrationRow,
    EventRow,
    InstanceRow,
    NoiseFloorRow,
    PositionRow,
    SchemaVersionRow,
    SessionRow,
    SlewRow,
    SpoolBatchRow,
)


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
        self._outbox_ready = False  # the schema has the outbox (checked at the first write)
        self._ship_columns: bool | None = None  # positions has them (checked at the first read)
        self._instance: str | None = None  # this database's instance id (read once)
        try:
            self._engine, self._lock = make_engine(parsed, connect_timeout_s)
        except (NoSuchModuleError, ImportError) as exc:
            raise StoreError(f"cannot use database URL {self.url}: {one_line(exc)}") from None
        # Writers of a file SQLite database take the write lock up front (engine.sqlite_on_begin).
        self._read = sessionmaker(self._engine, expire_on_commit=False)
        self._write = sessionmaker(
            self._engine.execution_options(**{WRITE_OPTION: True}), expire_on_commit=False
        )
        try:
            schema.check_on_open(self._engine, self._lock, self.url)
        except StoreError:
            self._engine.dispose()  # a refused database keeps no pooled connection
            raise

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
                raise StoreError(f"database {self.url}: {one_line(exc)}") from exc

    # ---- schema -------------------------------------------------------------------------
    def create_schema(self) -> None:
        """Bring the schema to this code's version with the migrations (idempotent).

        An empty database runs them all; one made by the release before migrations (an integer
        ``schema_version``, no ``alembic_version``) is stamped with the revision it matches,
        then upgraded; a migrated one is upgraded to the head (nothing to do when current).
        Everything runs in one transaction; a newer database is refused.
        """
        schema.upgrade(self._engine, self._lock, self.url)
        self._ship_columns = None

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
        return schema.recorded(self._engine, self._lock, self.url)

    # ---- sessions and positions ---------------------------------------------------------
    def add_session(self, source: str, meta: Mapping[str, Any] | None = None) -> int:
        """Record an acquisition session; returns its id."""
        with self._tx(write=True) as s:
            row = SessionRow(source=source, meta=dict(meta or {}))
            s.add(row)
            s.flush()
            self._enqueue(s, "session", [row.id])
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
        ``slews``: ``(first row, second row, recal.detect.slew_collect.ReducedSlew)`` between these windows,
        stored in the same transaction; row -1 is the window stored before, ``previous_id``
        (a slew whose first window is unknown is skipped). ``period_s``: gyro sample period.
        ``spool_key``: the batch's spool key; when positions with it are already stored (a
        replay after a kill between commit and spool delete) nothing is added and their ids are
        returned.
        """
        table = Positions.from_columns(columns, source=f"positions for session {session_id}")
        known = [c for c in POSITION_COLUMNS if c in table.columns]
        # the ship's columns, NULL where unknown; in extra on a database not yet upgraded to
        # them (revision 0005 moves them into their columns)
        ship = [c for c in SHIP_COLUMNS if c in table.columns] if self._has_ship_columns() else []
        extra = [c for c in table.columns if c not in POSITION_COLUMNS and c not in ship]
        # one row of values per window, only the columns given: an INSERT naming every mapped
        # column would fail on a database made before a column was added
        rows = [
            {
                "session_id": session_id,
                **{c: float(table.columns[c][i]) for c in known},
                **{c: finite_or_none(table.columns[c][i]) for c in ship},
                "extra": {c: finite_or_none(table.columns[c][i]) for c in extra},
            }
            for i in range(len(table))
        ]
        with self._tx(write=True) as s:
            if s.get(SessionRow, session_id) is None:
                raise UnknownSessionError(f"database {self.url}: unknown session {session_id}")
            if spool_key is not None and (done := keyed(s, spool_key)):
                return done  # stored before the spool could delete it: nothing twice
            stmt = insert(PositionRow).returning(PositionRow.id, sort_by_parameter_order=True)
            ids = [int(i) for i in s.scalars(stmt, rows)] if rows else []
            motion = slew_rows(slews, ids, previous_id, period_s)
            s.add_all(motion)
            s.flush()
            self._enqueue(s, "window", ids)  # one INSERT for the batch
            self._enqueue(s, "slew", [m.id for m in motion])
            if spool_key is not None:  # unique: a concurrent replay of it fails and rolls back
                s.add(SpoolBatchRow(key=spool_key, session_id=session_id, position_ids=ids))
            return ids

    def keyed_positions(self, spool_key: str) -> list[int]:
        """The ids of the positions stored with this spool key (empty: not stored)."""
        with self._tx() as s:
            return keyed(s, spool_key)

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
        return [slew_record(r) for r in rows if r.first_id in wanted and r.second_id in wanted]

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
        ship = self._has_ship_columns()
        if ship:
            query = query.options(*(undefer(getattr(PositionRow, c)) for c in SHIP_COLUMNS))
        with self._tx() as s:
            rows = list(s.scalars(query))
        ids = [r.id for r in rows]
        source = f"store {self.url}" + (f" positions {ids[0]}..{ids[-1]}" if ids else "")
        return Positions(columns=columns_of(rows, ship), source=source), ids

    def _has_ship_columns(self) -> bool:
        """The positions table has the ship's columns (schema version 5; a database opened
        before :meth:`create_schema` upgraded it may not)."""
        if self._ship_columns is None:
            try:
                with self._lock, self._engine.connect() as conn:
                    names = {c["name"] for c in inspect(conn).get_columns("positions")}
            except SQLAlchemyError as exc:
                raise StoreError(f"database {self.url}: {one_line(exc)}") from exc
            self._ship_columns = set(SHIP_COLUMNS) <= names
        return self._ship_columns

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
            created_at=as_utc(record.created_at),
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
            self._enqueue(s, "version", [row.id])
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
            return None if row is None else record_of(row)

    def calibration(self, version: int) -> CalibrationRecord | None:
        with self._tx() as s:
            row = s.get(CalibrationRow, version)
            return None if row is None else record_of(row)

    def history(self, limit: int = 50) -> list[CalibrationRecord]:
        """Calibrations, accepted or not, newest first."""
        query = select(CalibrationRow).order_by(CalibrationRow.id.desc()).limit(limit)
        with self._tx() as s:
            return [record_of(r) for r in s.scalars(query)]

    # ---- events -------------------------------------------------------------------------
    def add_event(self, kind: str, message: str, data: Mapping[str, Any] | None = None) -> int:
        with self._tx(write=True) as s:
            row = EventRow(kind=kind, message=message, data=None if data is None else dict(data))
            s.add(row)
            s.flush()
            self._enqueue(s, "event", [row.id])
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
                "created_at": as_utc(r.created_at).isoformat(),
            }

    def events(self, limit: int = 100) -> list[dict[str, Any]]:
        """Newest first, as JSON-ready dicts (``created_at`` in ISO 8601 UTC)."""
        query = select(EventRow).order_by(EventRow.id.desc()).limit(limit)
        with self._tx() as s:
            return [
                {
                    "id": r.id,
                    "created_at": as_utc(r.created_at).isoformat(),
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
            item["created_at"] = as_utc(item["created_at"])
            item["reasons"] = list(item["reasons"] or [])
        return out

    # ---- the outbox (fleet sync, docs/fleet.md) -------------------------------------------
    def _enqueue(self, s: Session, kind: str, ids: Sequence[int]) -> None:
        """Outbox rows for rows this transaction stores. A database not yet at the outbox's
        schema version gets none: migrating it gives every stored row its outbox row."""
        if not self._outbox_ready:
            found = s.scalar(select(func.max(SchemaVersionRow.version)))
            if found is None or found < outbox.SINCE_SCHEMA_VERSION:
                return
            self._outbox_ready = True  # schemas only move up under a running Store
        outbox.enqueue(s, kind, ids)

    def instance(self) -> str:
        """This database's instance id (a uuid4 made with the database, schema version 6),
        which every batch to the shore carries; ``""`` for a database not yet migrated to it
        (the shore's legacy instance)."""
        if self._instance is None:
            with self._tx() as s:
                if not inspect(s.connection()).has_table(InstanceRow.__tablename__):
                    return ""
                found = s.scalar(select(InstanceRow.instance).limit(1))
            if found is None:
                return ""
            self._instance = found  # made once with the database: never changes under a Store
        return self._instance

    def outbox(self, limit: int) -> list[OutboxEntry]:
        """The ``limit`` oldest rows still to send to the shore."""
        with self._tx() as s:
            return outbox.head(s, limit)

    def outbox_count(self) -> int:
        """Rows still to send to the shore."""
        with self._tx() as s:
            return outbox.count(s)

    def outbox_rows(self, entries: Sequence[OutboxEntry]) -> dict[tuple[str, int], dict[str, Any]]:
        """The stored rows the outbox entries name, by ``(kind, id)`` (service.store.outbox.load;
        a row no longer stored is absent)."""
        with self._tx() as s:
            return outbox.load(s, entries)

    def sync_acknowledge(
        self,
        seqs: Sequence[int],
        day: str | None = None,
        sent_bytes: int = 0,
        rows: int = 0,
        contact: datetime | None = None,
    ) -> int:
        """Delete the outbox rows the shore acknowledged and count the batch's traffic on
        ``day``, in one transaction; returns how many outbox rows were deleted."""
        with self._tx(write=True) as s:
            done = outbox.settle(s, seqs)
            if day is not None:
                outbox.add_traffic(s, day, sent_bytes, rows, contact)
            return done

    def sync_traffic_add(self, day: str, sent_bytes: int) -> None:
        """Count bytes sent on ``day`` without an acknowledgement."""
        with self._tx(write=True) as s:
            outbox.add_traffic(s, day, sent_bytes)

    def sync_traffic(self, since_day: str) -> list[dict[str, Any]]:
        """The link's traffic per UTC day from ``since_day`` on (days with any), oldest first."""
        with self._tx() as s:
            return outbox.traffic(s, since_day)

    def sync_last_contact(self) -> datetime | None:
        """When the shore last answered (None: never)."""
        with self._tx() as s:
            return outbox.last_contact(s)


def keyed(s: Session, spool_key: str) -> list[int]:
    """The position ids stored with a spool batch key (empty: not stored)."""
    row = s.get(SpoolBatchRow, spool_key)
    return [] if row is None else [int(i) for i in row.position_ids]
