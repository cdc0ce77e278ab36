"""The outbox: one row per stored row still to send to the shore (docs/fleet.md), written in
the same transaction as the row itself, read oldest first and deleted once acknowledged; and
the link's traffic per UTC day, kept in the acknowledgement's transaction.

Functions over an open ORM session (the :class:`~service.store.Store` owns the transactions).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import delete, func, insert, select
from sqlalchemy.orm import Session, undefer

from recal.model.positions import SHIP_COLUMNS
from service.store.codec import as_utc, record_of, slew_record
from service.store.rows import (
    POSITION_COLUMNS,
    CalibrationRow,
    EventRow,
    OutboxRow,
    PositionRow,
    SessionRow,
    SlewRow,
    SyncDayRow,
)

#: The schema version that made the outbox (migration 0004, which gave every row stored
#: before it its outbox row).
SINCE_SCHEMA_VERSION = 4
#: The kinds of rows sent, as the wire format names them (docs/fleet.md).
KINDS = ("session", "window", "slew", "version", "event")


@dataclass(frozen=True)
class OutboxEntry:
    """One row still to send: its outbox sequence number, kind and row id."""

    seq: int
    kind: str
    ref_id: int


def enqueue(s: Session, kind: str, ids: Iterable[int]) -> None:
    """Outbox rows for stored rows of ``kind`` (one INSERT for many)."""
    assert kind in KINDS, kind
    rows = [{"kind": kind, "ref_id": int(i)} for i in ids]
    if rows:
        s.execute(insert(OutboxRow), rows)


def head(s: Session, limit: int) -> list[OutboxEntry]:
    """The ``limit`` oldest outbox rows."""
    query = select(OutboxRow.seq, OutboxRow.kind, OutboxRow.ref_id).order_by(OutboxRow.seq)
    return [OutboxEntry(*row) for row in s.execute(query.limit(limit))]


def count(s: Session) -> int:
    return int(s.scalar(select(func.count()).select_from(OutboxRow)) or 0)


def settle(s: Session, seqs: Sequence[int]) -> int:
    """Delete these outbox rows (what the shore acknowledged); returns how many were there."""
    done = 0
    for i in range(0, len(seqs), 500):  # bounded IN lists
        chunk = [int(q) for q in seqs[i : i + 500]]
        done += s.execute(delete(OutboxRow).where(OutboxRow.seq.in_(chunk))).rowcount or 0
    return done


def load(s: Session, entries: Sequence[OutboxEntry]) -> dict[tuple[str, int], dict[str, Any]]:
    """The rows the entries name, by ``(kind, id)``: each a dict with ``at`` (UTC) and the
    row's fields (``record`` for a version, a CalibrationRecord; ``slew`` for a slew, a
    SlewRecord). A row no longer stored is absent."""
    wanted: dict[str, list[int]] = {}
    for e in entries:
        wanted.setdefault(e.kind, []).append(e.ref_id)
    out: dict[tuple[str, int], dict[str, Any]] = {}
    for kind, ids in wanted.items():
        for i in range(0, len(ids), 500):
            out.update(_LOADERS[kind](s, ids[i : i + 500]))
    return out


def _sessions(s: Session, ids: list[int]) -> dict[tuple[str, int], dict[str, Any]]:
    rows = s.scalars(select(SessionRow).where(SessionRow.id.in_(ids)))
    return {
        ("session", r.id): {"at": as_utc(r.created_at), "source": r.source, "meta": r.meta}
        for r in rows
    }


def _windows(s: Session, ids: list[int]) -> dict[tuple[str, int], dict[str, Any]]:
    out = {}
    ship = [getattr(PositionRow, c) for c in SHIP_COLUMNS]
    query = select(PositionRow).where(PositionRow.id.in_(ids)).options(*map(undefer, ship))
    for r in s.scalars(query):
        columns = {c: getattr(r, c) for c in POSITION_COLUMNS} | dict(r.extra or {})
        columns |= {c: v for c in SHIP_COLUMNS if (v := getattr(r, c)) is not None}
        out["window", r.id] = {"at": as_utc(r.created_at), "session": r.session_id,
                               "columns": columns}  # fmt: skip
    return out


def _slews(s: Session, ids: list[int]) -> dict[tuple[str, int], dict[str, Any]]:
    # a slew is stored with its second window: that window's time is the slew's
    query = (
        select(SlewRow, PositionRow.created_at)
        .join(PositionRow, PositionRow.id == SlewRow.second_id)
        .where(SlewRow.id.in_(ids))
    )
    return {
        ("slew", r.id): {"at": as_utc(at), "slew": slew_record(r)} for r, at in s.execute(query)
    }


def _versions(s: Session, ids: list[int]) -> dict[tuple[str, int], dict[str, Any]]:
    rows = s.scalars(select(CalibrationRow).where(CalibrationRow.id.in_(ids)))
    return {("version", r.id): {"at": as_utc(r.created_at), "record": record_of(r)} for r in rows}


def _events(s: Session, ids: list[int]) -> dict[tuple[str, int], dict[str, Any]]:
    rows = s.scalars(select(EventRow).where(EventRow.id.in_(ids)))
    return {
        ("event", r.id): {
            "at": as_utc(r.created_at),
            "kind": r.kind,
            "message": r.message,
            "data": r.data,
        }  # fmt: skip
        for r in rows
    }


_LOADERS = {"session": _sessions, "window": _windows, "slew": _slews, "version": _versions,
            "event": _events}  # fmt: skip


# ---- the link's traffic per UTC day -------------------------------------------------------


def add_traffic(
    s: Session, day: str, sent_bytes: int, rows: int = 0, contact: datetime | None = None
) -> None:
    """Count ``sent_bytes`` (compressed, every attempt) and ``rows`` acknowledged on ``day``
    (``YYYY-MM-DD``, UTC); ``contact``: when the shore last answered."""
    row = s.get(SyncDayRow, day)
    if row is None:
        row = SyncDayRow(day=day, sent_bytes=0, rows=0, batches=0)
        s.add(row)
    row.sent_bytes += int(sent_bytes)
    row.rows += int(rows)
    if contact is not None:
        row.batches += 1
        row.last_contact = contact


def traffic(s: Session, since_day: str) -> list[dict[str, Any]]:
    """The days from ``since_day`` on that saw traffic, oldest first."""
    query = select(SyncDayRow).where(SyncDayRow.day >= since_day).order_by(SyncDayRow.day)
    return [
        {"day": r.day, "bytes": r.sent_bytes, "rows": r.rows, "batches": r.batches}
        for r in s.scalars(query)
    ]


def last_contact(s: Session) -> datetime | None:
    at = s.scalar(select(func.max(SyncDayRow.last_contact)))
    return None if at is None else as_utc(at)
