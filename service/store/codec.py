"""Conversions between what callers hold and what the rows store: JSON-ready values, UTC
times, position columns, calibration records and slews packed as float64 bytes."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

import numpy as np

from recal.model.positions import SHIP_COLUMNS
from service.store.records import CalibrationRecord, SlewRecord
from service.store.rows import POSITION_COLUMNS, CalibrationRow, PositionRow, SlewRow


def plain(obj: Any) -> Any:
    """JSON-ready copy: numpy to Python, NaN/inf to None (PostgreSQL's json rejects NaN)."""
    if isinstance(obj, Mapping):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | np.ndarray):
        return [plain(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, datetime):
        return obj.isoformat()
    return obj


def dumps(obj: Any) -> str:
    return json.dumps(plain(obj), allow_nan=False)


def as_utc(value: datetime) -> datetime:
    """SQLite hands back naive datetimes; everything stored is UTC."""
    return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


def utc_day(at: datetime | None = None) -> str:
    """``YYYY-MM-DD`` of ``at``'s UTC day (default now): the day a link's traffic is counted
    under, on the vessel (sync statistics) and on shore (``fleet_link_days``)."""
    return as_utc(at or datetime.now(UTC)).date().isoformat()


def finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def columns_of(rows: Sequence[PositionRow], ship: bool = False) -> dict[str, np.ndarray]:
    """The columns present in every row (stored ones, then ``extra`` ones), NULL as NaN, and the
    ship's columns (``SHIP_COLUMNS``: their own, loaded when ``ship``, else from ``extra``) where
    any row has a value, NaN where the ship's sensors did not cover a window."""
    if not rows:
        return {}
    cols: dict[str, np.ndarray] = {}
    for name in POSITION_COLUMNS:
        values = [getattr(r, name) for r in rows]
        if all(v is not None for v in values):
            cols[name] = np.array(values, dtype=float)
    for name in SHIP_COLUMNS:  # in extra where the database had no such column yet
        values = [getattr(r, name) if ship else None for r in rows]
        values = [r.extra.get(name) if v is None else v for r, v in zip(rows, values)]
        if any(v is not None for v in values):
            cols[name] = np.array([math.nan if v is None else v for v in values], dtype=float)
    shared = [k for k in rows[0].extra if k not in cols and all(k in r.extra for r in rows)]
    # ... and the windows' own flags that only some batches carry: a hull window whose vertical
    # rate is no measurement (gyro_vertical 0, recal.detect.creep) must stay one beside windows
    # stored before or with the ship's heading (NaN there: a measurement)
    partial = [k for k in PARTIAL_EXTRAS if k not in cols and k not in shared
               and any(k in r.extra for r in rows)]  # fmt: skip
    for name in [*shared, *partial]:
        cols[name] = np.array(
            [math.nan if r.extra.get(name) is None else r.extra[name] for r in rows], dtype=float
        )
    return cols


#: Extra columns kept even where only some rows have them (NaN in the others).
PARTIAL_EXTRAS = ("gyro_vertical", "creep_dph")


def record_of(row: CalibrationRow) -> CalibrationRecord:
    return CalibrationRecord(
        version=row.id,
        created_at=as_utc(row.created_at),
        trigger=row.trigger,
        method=row.method,
        accepted=row.accepted,
        reasons=list(row.reasons),
        document=row.document,
        positions_used=list(row.positions_used),
        prior_version=row.prior_version,
    )


def slew_rows(
    slews: Sequence[tuple[int, int, Any]],
    ids: list[int],
    previous_id: int | None,
    period_s: float | None,
) -> list[SlewRow]:
    """Rows for ``(first row, second row, ReducedSlew)`` between windows stored as ``ids``
    (row -1: ``previous_id``; a slew without its first window or a period is skipped)."""
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


def slew_record(row: SlewRow) -> SlewRecord:
    ref = groups = None
    if row.data is not None:
        v = np.frombuffer(row.data, dtype=np.float64)
        ref, body = v[:3].copy(), v[3:].reshape(row.groups, 10)
        groups = (body[:, 0].astype(np.int64), body[:, 1:4].copy(), body[:, 4:7].copy(),
                  body[:, 7:10].copy())  # fmt: skip
    return SlewRecord(row.first_id, row.second_id, row.period_s, row.samples, ref, groups,
                      row.dropped)  # fmt: skip
