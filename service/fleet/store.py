"""The shore's repository: units and their tokens, batches stored once, the fleet queries.

Like the vessel's :class:`service.store.repository.Store`, every public call opens its own short-lived
session in one transaction, so one :class:`FleetStore` is shared by the server's threads, and
database failures surface as :class:`service.store.errors.StoreError` with a one-line message.

Delivery is at least once, storage once (docs/fleet.md): a batch goes in one transaction, each
row an insert that does nothing when its key (unit, vessel database instance, vessel row id) is
already stored (ON CONFLICT DO NOTHING, SQLite and PostgreSQL); a row not inserted is then
compared by content with the one stored, and kept in ``fleet_conflicts`` when it differs. Concurrent batches of one unit take its unit row
first (an UPDATE of ``last_contact``), so they run one after the other; rows are inserted in
key order, so batches of different units never wait on each other in a cycle.
"""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, NamedTuple

from sqlalchemy import func, select, text, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, IntegrityError, NoSuchModuleError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from service.fleet.batch import Batch, IncomingRow, content_digest
from service.fleet.schema import (
    KINDS,
    MAX_SERIAL,
    ConflictRow,
    EventRow,
    IngestRow,
    LinkDayRow,
    UnitRow,
    VersionRow,
)
from service.fleet.unit_state import newest_rows
from service.store.codec import as_utc, utc_day
from service.store.engine import make_engine
from service.store.errors import StoreError, one_line

#: A unit's serial: what ``recal fleet add-unit`` accepts.
SERIAL = re.compile(rf"[A-Za-z0-9][A-Za-z0-9._-]{{0,{MAX_SERIAL - 1}}}")
#: Rows per INSERT statement (SQLite allows 32766 bound values; a row binds 6 to 9).
CHUNK_ROWS = 500
#: Days of ingest log ``unit()`` sums into bytes per day.
LINK_DAYS = 30
#: Newest conflicts ``unit()`` shows whole.
CONFLICTS_SHOWN = 20
#: Advisory lock key of the shore's migrations on PostgreSQL (the vessel's is 7310599).
_MIGRATION_LOCK = 7310600


class UnitExistsError(StoreError):
    """``add_unit`` of a serial already registered (without ``rotate``)."""


class UnknownUnitError(StoreError):
    """A serial this shore does not know."""


class Ingested(NamedTuple):
    """What :meth:`FleetStore.ingest` made of a batch: rows stored (new), duplicates (stored
    already with the same content) and conflicts (stored already with other content: kept in
    ``fleet_conflicts``, never dropped)."""

    stored: int
    duplicates: int
    conflicts: int


@dataclass(frozen=True)
class Unit:
    id: int
    serial: str
    model: str | None


def token_hash(token: str) -> str:
    """What the shore keeps of a token: its sha256, in hex."""
    return hashlib.sha256(token.encode()).hexdigest()


def new_token() -> str:
    return secrets.token_urlsafe(32)


class FleetStore:
    """Repository over one database URL (``postgresql+psycopg://...`` or ``sqlite:///FILE``)."""

    def __init__(self, url: str, *, connect_timeout_s: float = 5.0) -> None:
        try:
            parsed = make_url(url)
        except ArgumentError:
            raise StoreError(
                f"bad database URL {url!r}: expected e.g. postgresql+psycopg://user@host/fleet "
                "or sqlite:///fleet.db"
            ) from None
        self.url = parsed.render_as_string(hide_password=True)
        if parsed.get_backend_name() not in ("postgresql", "sqlite"):
            raise StoreError(f"database URL {self.url}: the shore runs on PostgreSQL or SQLite")
        try:
            # the vessel Store's connection rules: SQLite in WAL, writers BEGIN IMMEDIATE
            self._engine, self._lock = make_engine(parsed, connect_timeout_s)
        except (NoSuchModuleError, ImportError) as exc:
            raise StoreError(f"cannot use database URL {self.url}: {one_line(exc)}") from None
        self._read = sessionmaker(self._engine, expire_on_commit=False)
        self._write = sessionmaker(
            self._engine.execution_options(recal_write=True), expire_on_commit=False
        )

    def close(self) -> None:
        self._engine.dispose()

    @property
    def dialect(self) -> str:
        return self._engine.dialect.name

    @contextmanager
    def _tx(self, write: bool = False) -> Iterator[Session]:
        maker = self._write if write else self._read
        with self._lock:
            try:
                with maker.begin() as session:
                    yield session
            except StoreError:
                raise
            except SQLAlchemyError as exc:
                raise StoreError(f"database {self.url}: {one_line(exc)}") from exc

    # ---- schema -------------------------------------------------------------------------
    def create_schema(self) -> None:
        """Bring the shore's tables to this code's revision (idempotent, one transaction);
        a database at a revision this code does not know is refused."""
        from alembic import command
        from alembic.util import CommandError

        from service.fleet.migrations import alembic_config

        try:
            with (
                self._lock,
                self._engine.execution_options(recal_write=True).connect() as conn,
                conn.begin(),
            ):
                if self.dialect == "postgresql":  # two shores starting at once: one migrates
                    conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _MIGRATION_LOCK})
                self._require_known(conn)
                command.upgrade(alembic_config(conn), "head")
        except SQLAlchemyError as exc:
            raise StoreError(f"database {self.url}: {one_line(exc)}") from exc
        except CommandError as exc:
            raise StoreError(f"database {self.url}: migration failed: {one_line(exc)}") from exc

    def schema_revision(self) -> str | None:
        """The shore revision recorded (None before :meth:`create_schema`)."""
        try:
            with self._lock, self._engine.connect() as conn:
                found = self._recorded(conn)
        except SQLAlchemyError as exc:
            raise StoreError(f"database {self.url}: {one_line(exc)}") from exc
        return ",".join(found) or None

    def _recorded(self, conn: Any) -> list[str]:
        from sqlalchemy import inspect

        from service.fleet.migrations import VERSION_TABLE

        if not inspect(conn).has_table(VERSION_TABLE):
            return []
        return sorted(conn.execute(text(f"SELECT version_num FROM {VERSION_TABLE}")).scalars())

    def _require_known(self, conn: Any) -> None:
        from service.fleet.migrations import head, revisions

        unknown = [r for r in self._recorded(conn) if r not in revisions()]
        if unknown:
            raise StoreError(
                f"database {self.url} has shore schema revision {', '.join(unknown)}, newer "
                f"than this code knows ({head()}): upgrade fog-recal"
            )

    # ---- units --------------------------------------------------------------------------
    def add_unit(self, serial: str, model: str | None = None, *, rotate: bool = False) -> str:
        """Register ``serial`` and return its new token (kept only as a hash). ``rotate``: a
        registered unit gets a new token, the old one stops working (``model`` is updated
        when given). :class:`UnitExistsError` for a registered serial without ``rotate``,
        :class:`UnknownUnitError` for rotating an unknown one."""
        if not SERIAL.fullmatch(serial):
            raise StoreError(
                f"serial {serial!r}: use 1 to {MAX_SERIAL} letters, digits, '.', '-' or '_' "
                "(starting with a letter or digit)"
            )
        token = new_token()
        try:
            with self._tx(write=True) as s:
                row = s.scalar(select(UnitRow).where(UnitRow.serial == serial))
                if row is None and rotate:
                    raise UnknownUnitError(f"unit {serial} is not registered: nothing to rotate")
                if row is not None and not rotate:
                    raise UnitExistsError(
                        f"unit {serial} is already registered (--rotate issues a new token)"
                    )
                if row is None:
                    row = UnitRow(serial=serial, created_at=datetime.now(UTC))
                    s.add(row)
                row.token_hash = token_hash(token)
                if model is not None:
                    row.model = model
        except StoreError as exc:
            if isinstance(exc.__cause__, IntegrityError):  # registered meanwhile
                raise UnitExistsError(f"unit {serial} is already registered") from None
            raise
        return token

    def unit_of_token(self, token: str) -> Unit | None:
        """The unit whose token this is, or None."""
        digest = token_hash(token)
        with self._tx() as s:
            row = s.scalar(select(UnitRow).where(UnitRow.token_hash == digest))
        if row is None or not hmac.compare_digest(row.token_hash, digest):
            return None
        return Unit(row.id, row.serial, row.model)

    def unit_by_serial(self, serial: str) -> Unit | None:
        with self._tx() as s:
            row = s.scalar(select(UnitRow).where(UnitRow.serial == serial))
        return None if row is None else Unit(row.id, row.serial, row.model)

    # ---- ingest -------------------------------------------------------------------------
    def ingest(self, unit: Unit, batch: Batch, compressed_bytes: int) -> Ingested:
        """Store ``batch`` of ``unit`` in one transaction: (rows stored, duplicates, conflicts).

        A row's key is (unit, the batch's ``instance``, kind, vessel row id). A row whose key
        is stored already with the same content (:func:`~service.fleet.batch.content_digest`)
        is a duplicate and changes nothing; with other content it is a conflict, kept whole in
        ``fleet_conflicts`` (once per content: a retried batch adds nothing) and counted on the
        unit's row. A key repeated within the batch: the first is the row, a later one with
        other content a conflict."""
        now = datetime.now(UTC)
        insert = postgresql.insert if self.dialect == "postgresql" else sqlite.insert
        instance = batch.instance
        by_kind: dict[str, dict[int, dict[str, Any]]] = {k: {} for k in KINDS}
        conflicting: list[tuple[IncomingRow, str]] = []  # (row, the digest it differs from)
        for r in batch.rows:
            values = {"unit_id": unit.id, "vessel_id": r.id, "instance": instance, "at": r.at,
                      "received_at": now, "data": r.data, "digest": r.digest, **r.columns}  # fmt: skip
            first = by_kind[r.kind].setdefault(r.id, values)
            if first is not values and first["digest"] != r.digest:
                conflicting.append((r, first["digest"]))
        new: dict[str, list[int]] = {k: [] for k in KINDS}
        incoming = {(r.kind, r.id): r for r in reversed(batch.rows)}  # the first of each key
        with self._tx(write=True) as s:
            # the unit's row first: one unit's batches take turns, whatever their rows
            s.execute(update(UnitRow).where(UnitRow.id == unit.id)
                      .values(last_contact=now, instance=instance,
                              backlog=batch.backlog))  # fmt: skip
            for kind, rows in by_kind.items():
                if not rows:
                    continue
                table = KINDS[kind].__table__
                ordered = [rows[k] for k in sorted(rows)]
                # one compiled statement per kind, sent as multi-row INSERTs (SQLAlchemy's
                # insertmanyvalues): compiling a 500-row VALUES per batch cost 3x the insert
                statement = (
                    insert(table)
                    .on_conflict_do_nothing(index_elements=["unit_id", "vessel_id", "instance"])
                    .returning(table.c.vessel_id)  # the rows inserted, not those ignored
                )
                for i in range(0, len(ordered), CHUNK_ROWS):
                    found = s.connection().execute(statement, ordered[i : i + CHUNK_ROWS])
                    new[kind] += found.scalars().all()
                # the keys already stored: the same content (a retry) or not (a conflict)
                inserted = set(new[kind])
                known = [k for k in sorted(rows) if k not in inserted]
                for vessel_id, digest in self._stored_digests(s, KINDS[kind], unit.id, instance,
                                                              known):  # fmt: skip
                    if digest != rows[vessel_id]["digest"]:
                        conflicting.append((incoming[(kind, vessel_id)], digest))
            stored = sum(len(ids) for ids in new.values())
            recorded = self._record_conflicts(s, insert, unit.id, instance, now, conflicting)
            values: dict[str, Any] = {}
            if new["version"] or new["window"]:  # the unit's counts (GET /fleet/units)
                values["n_versions"] = UnitRow.n_versions + len(new["version"])
                values["n_windows"] = UnitRow.n_windows + len(new["window"])
            rejected = sum(1 for v in new["version"] if not by_kind["version"][v]["accepted"])
            if rejected:  # the overview's count (migration 0008)
                values["n_rejected"] = UnitRow.n_rejected + rejected
            if recorded:
                values["n_conflicts"] = UnitRow.n_conflicts + recorded
            values |= newest_rows(
                unit.id,
                versions=bool(new["version"]),
                drift=any(by_kind["event"][i].get("kind") == "drift" for i in new["event"]),
            )
            if values:
                s.execute(update(UnitRow).where(UnitRow.id == unit.id).values(**values))
            s.add(IngestRow(unit_id=unit.id, at=now, compressed_bytes=compressed_bytes,
                            rows=len(batch.rows), stored=stored, backlog=batch.backlog))  # fmt: skip
            day = insert(LinkDayRow).values(
                unit_id=unit.id, day=utc_day(now), batches=1, rows=len(batch.rows),
                stored=stored, compressed_bytes=compressed_bytes,
            )  # fmt: skip
            s.execute(day.on_conflict_do_update(
                index_elements=["unit_id", "day"],
                set_={"batches": LinkDayRow.batches + 1, "rows": LinkDayRow.rows + len(batch.rows),
                      "stored": LinkDayRow.stored + stored,
                      "compressed_bytes": LinkDayRow.compressed_bytes + compressed_bytes},
            ))  # fmt: skip
        n_conflicts = len(conflicting)
        return Ingested(stored, len(batch.rows) - stored - n_conflicts, n_conflicts)

    @staticmethod
    def _stored_digests(
        s: Session, table: Any, unit_id: int, instance: str, ids: list[int]
    ) -> Iterator[tuple[int, str]]:
        """(vessel row id, content digest) of the stored rows of ``ids``; a row stored before
        digests were kept (migration 0007) is digested from its document as stored."""
        for i in range(0, len(ids), CHUNK_ROWS):
            chunk = ids[i : i + CHUNK_ROWS]
            where = (table.unit_id == unit_id, table.instance == instance,
                     table.vessel_id.in_(chunk))  # fmt: skip
            older = []
            for vessel_id, digest in s.execute(select(table.vessel_id, table.digest).where(*where)):
                if digest is None:
                    older.append(vessel_id)
                else:
                    yield vessel_id, digest
            if older:
                found = s.execute(select(table.vessel_id, table.data)
                                  .where(*where[:2], table.vessel_id.in_(older)))  # fmt: skip
                for vessel_id, data in found:
                    yield vessel_id, content_digest(data)

    @staticmethod
    def _record_conflicts(
        s: Session,
        insert: Any,
        unit_id: int,
        instance: str,
        now: datetime,
        conflicting: list[tuple[IncomingRow, str]],
    ) -> int:
        """Keep the conflicting rows whole (once per content); returns how many are new."""
        if not conflicting:
            return 0
        table = ConflictRow.__table__
        statement = (
            insert(table)
            .on_conflict_do_nothing(
                index_elements=["unit_id", "kind", "instance", "vessel_id", "digest"]
            )
            .returning(table.c.id)
        )
        rows = [{"unit_id": unit_id, "kind": r.kind, "instance": instance, "vessel_id": r.id,
                 "at": r.at, "received_at": now, "digest": r.digest, "stored_digest": stored,
                 "data": r.data} for r, stored in conflicting]  # fmt: skip
        recorded = 0
        for i in range(0, len(rows), CHUNK_ROWS):
            recorded += len(s.connection().execute(statement, rows[i : i + CHUNK_ROWS]).all())
        return recorded

    # ---- queries ------------------------------------------------------------------------
    def units(self, only: int | None = None) -> list[dict[str, Any]]:
        """Every unit (or only the one of id ``only``), by serial: ``unit``, ``model``,
        ``versions``, ``windows``, ``current_version`` (and its ``current_instance``),
        ``last_contact``, ``instance`` (of the latest batch), ``conflicts`` (the counts kept
        on the unit's row by :meth:`ingest`: no vessel row is read)."""
        query = select(UnitRow).order_by(UnitRow.serial)
        if only is not None:
            query = query.where(UnitRow.id == only)
        with self._tx() as s:
            rows = s.scalars(query).all()
        return [
            {
                "unit": u.serial,
                "model": u.model,
                "versions": u.n_versions or 0,
                "windows": u.n_windows or 0,
                "current_version": u.current_version,
                "current_instance": u.current_instance,
                "last_contact": iso_time(u.last_contact),
                "instance": u.instance,
                "conflicts": u.n_conflicts or 0,
            }
            for u in rows
        ]

    def unit(self, unit: Unit, days: int = LINK_DAYS) -> dict[str, Any]:
        """One unit with its link state: the :meth:`units` fields plus ``created_at``, rows
        stored per kind, per UTC day of the last ``days`` the batches, rows and compressed
        bytes received, and its newest conflicts (:meth:`conflicts`) as ``conflict_rows``."""
        (out,) = self.units(only=unit.id)
        since = datetime.now(UTC) - timedelta(days=days)
        if self.dialect == "postgresql":
            day = func.to_char(func.timezone("UTC", IngestRow.at), "YYYY-MM-DD")
        else:
            day = func.strftime("%Y-%m-%d", IngestRow.at)
        link = (
            select(
                day.label("day"),
                func.count(),
                func.sum(IngestRow.rows),
                func.sum(IngestRow.stored),
                func.sum(IngestRow.compressed_bytes),
            )
            .where(IngestRow.unit_id == unit.id, IngestRow.at >= since)
            .group_by(day)
            .order_by(day)
        )
        with self._tx() as s:
            created = s.scalar(select(UnitRow.created_at).where(UnitRow.id == unit.id))
            stored = {kind: s.scalar(select(func.count()).where(table.unit_id == unit.id)) or 0
                      for kind, table in KINDS.items()}  # fmt: skip
            per_day = s.execute(link).all()
        out["created_at"] = iso_time(created)
        out["rows"] = stored
        out["conflict_rows"] = self.conflicts(unit, limit=CONFLICTS_SHOWN)
        out["link"] = [
            {"day": d, "batches": n, "rows": int(r or 0), "stored": int(st or 0),
             "compressed_bytes": int(b or 0)}
            for d, n, r, st, b in per_day
        ]  # fmt: skip
        return out

    def conflicts(self, unit: Unit, limit: int = 100) -> list[dict[str, Any]]:
        """The unit's conflicts, newest first: each the row received whole (``kind``,
        ``instance``, ``id``, ``at``, ``data``) with ``received_at``, its ``digest`` and the
        ``stored_digest`` of the row stored under that key."""
        query = (
            select(ConflictRow)
            .where(ConflictRow.unit_id == unit.id)
            .order_by(ConflictRow.received_at.desc(), ConflictRow.id.desc())
            .limit(limit)
        )
        with self._tx() as s:
            found = s.scalars(query).all()
        return [
            {"kind": c.kind, "instance": c.instance, "id": c.vessel_id, "at": iso_time(c.at),
             "received_at": iso_time(c.received_at), "digest": c.digest,
             "stored_digest": c.stored_digest, "data": c.data}
            for c in found
        ]  # fmt: skip

    def rows(
        self,
        kind: str,
        unit: Unit,
        *,
        since: datetime | None = None,
        until: datetime | None = None,
        after: int | None = None,
        limit: int = 100,
        event_kind: str | None = None,
        instance: str | None = None,
    ) -> list[dict[str, Any]]:
        """One unit's rows of ``kind``, by vessel row id then instance (a rebuilt vessel's ids
        start at 1 again: its rows and the older database's interleave, each with its
        ``instance``): ``since`` <= time < ``until``, vessel row id > ``after`` (the next
        page), at most ``limit`` (a page ends after the last row of its last vessel row id, so
        ``after`` misses no instance's row: a page may hold a few more); ``instance``: that
        vessel database's rows alone."""
        table = KINDS[kind]
        query = select(table).where(table.unit_id == unit.id)
        if instance is not None:
            query = query.where(table.instance == instance)
        query = _between(query, table, since, until)
        if event_kind is not None:
            query = query.where(EventRow.kind == event_kind)
        rest = query  # the rest of the last vessel row id's rows, below
        if after is not None:
            query = query.where(table.vessel_id > after)
        query = query.order_by(table.vessel_id, table.instance).limit(limit)
        with self._tx() as s:
            if since is not None:
                # where the time range starts in id order (an index-only scan of (unit, at,
                # vessel id)): the pages then start there, instead of reading the unit's older
                # rows one by one only to drop them (0.8 s in mid-history, migration 0004)
                # (+ 0: PostgreSQL would turn a plain min() into the slow walk in id order)
                first = select(func.min(table.vessel_id + 0)).where(table.unit_id == unit.id)
                first = s.scalar(_between(first, table, since, until))
                if first is None:
                    return []
                query = query.where(table.vessel_id >= first)
            found = list(s.scalars(query).all())
            if len(found) == limit and instance is None:  # the other instances of the last id
                last = found[-1]
                rest = rest.where(table.vessel_id == last.vessel_id,
                                  table.instance > last.instance).order_by(table.instance)  # fmt: skip
                found += s.scalars(rest).all()
        return [_out(kind, r) for r in found]

    def fleet_versions(
        self,
        *,
        only: int | None = None,
        model: str | None = None,
        accepted: bool | None = None,
        since: datetime | None = None,
        until: datetime | None = None,
        limit: int = 100,
    ) -> list[dict[str, Any]]:
        """Versions across the fleet (or of unit id ``only``), oldest first, each with its
        ``unit`` and ``model``."""
        query = select(VersionRow, UnitRow.serial, UnitRow.model).join(
            UnitRow, UnitRow.id == VersionRow.unit_id
        )
        if only is not None:
            query = query.where(VersionRow.unit_id == only)
        if model is not None:
            query = query.where(UnitRow.model == model)
        if accepted is not None:
            query = query.where(VersionRow.accepted.is_(accepted))
        query = _between(query, VersionRow, since, until)
        query = query.order_by(VersionRow.at, VersionRow.id).limit(limit)
        with self._tx() as s:
            found = s.execute(query).all()
        return [{"unit": serial, "model": m, **_out("version", r)} for r, serial, m in found]


def _between(query: Any, table: Any, since: datetime | None, until: datetime | None) -> Any:
    if since is not None:
        query = query.where(table.at >= since.astimezone(UTC))
    if until is not None:
        query = query.where(table.at < until.astimezone(UTC))
    return query


def iso_time(value: datetime | None) -> str | None:
    """ISO 8601 UTC with a Z, as the vessel writes times."""
    if value is None:
        return None
    return as_utc(value).isoformat().replace("+00:00", "Z")


def _out(kind: str, row: Any) -> dict[str, Any]:
    """A stored row as the API serves it."""
    if kind == "version":
        return {
            "version": row.vessel_id,
            "instance": row.instance,
            "created_at": iso_time(row.at),
            "accepted": row.accepted,
            "trigger": row.trigger,
            "method": row.method,
            "received_at": iso_time(row.received_at),
            "document": row.data,
        }
    out = {"id": row.vessel_id, "instance": row.instance, "at": iso_time(row.at),
           "received_at": iso_time(row.received_at)}  # fmt: skip
    if kind == "event":
        out["kind"] = row.kind
    return {**out, "data": row.data}


__all__: Sequence[str] = ("FleetStore", "Ingested", "Unit", "UnitExistsError", "UnknownUnitError")
