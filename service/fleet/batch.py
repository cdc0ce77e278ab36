"""One ingest batch, format 1 (docs/fleet.md#wire-format-format-1): decompressed, parsed and
checked whole before anything is stored.

:func:`read_batch` turns the request body into a :class:`Batch` of :class:`IncomingRow`, with
the columns the shore filters on pulled out of each row's document, or raises
:class:`BatchError` with the HTTP status (413, 422) and a one-line message naming the first bad
row.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import zlib
from dataclasses import dataclass, field
from datetime import UTC, datetime
from decimal import Decimal
from typing import Any

from recal.fleet.history import flat_version
from service.fleet.priors import coefficient_names

#: The wire format this shore reads.
FORMAT = 1
#: Largest vessel row id or count: the largest integer every JSON reader holds exactly (a
#: double, as the dashboard's JavaScript reads it; PostgreSQL's BIGINT holds more).
MAX_ID = 2**53 - 1
#: Longest ``trigger``, ``method`` or event ``kind`` kept as a column (the schema's String(64)).
MAX_NAME = 64
#: A vessel database's instance id: a uuid4 as the vessel writes it (at most 36 characters of
#: letters, digits and ``-``; the schema's String(36)). Absent or "": the legacy instance.
INSTANCE = re.compile(r"[A-Za-z0-9-]{1,36}")


class BatchError(ValueError):
    """A batch that is refused whole: ``status`` 413 (too large) or 422 (malformed)."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class IncomingRow:
    kind: str
    id: int
    at: datetime
    data: dict[str, Any]
    #: the kind's filter columns (service.fleet.schema): accepted/trigger/method, kind
    columns: dict[str, Any] = field(default_factory=dict)
    #: :func:`content_digest` of ``data``: what a row received again is compared by
    digest: str = ""


@dataclass(frozen=True)
class Batch:
    unit: str
    sent_at: datetime | None
    rows: list[IncomingRow]
    #: outbox rows the vessel still holds besides this batch (optional ``backlog``), or None
    backlog: int | None = None
    #: the vessel database that made the rows (optional ``instance``; "" the legacy instance)
    instance: str = ""


def decompress(body: bytes, encoding: str | None, max_bytes: int) -> bytes:
    """The body without its ``Content-Encoding`` (gzip or none), at most ``max_bytes``."""
    coding = (encoding or "identity").strip().lower()
    if coding == "identity":
        return body
    if coding != "gzip":
        raise BatchError(422, f"Content-Encoding {coding} is not gzip")
    inflater = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
    try:
        out = inflater.decompress(body, max_bytes + 1)  # stops early: a small bomb stays small
    except zlib.error as exc:
        raise BatchError(422, f"body is not valid gzip: {exc}") from None
    if len(out) > max_bytes:
        raise BatchError(413, f"batch is over {max_bytes} bytes decompressed")
    if not inflater.eof:
        raise BatchError(422, "body is cut short: the gzip stream does not end")
    return out


def read_batch(body: bytes, encoding: str | None, max_bytes: int) -> Batch:
    """The checked batch of a request body; :class:`BatchError` for anything wrong in it."""
    raw = decompress(body, encoding, max_bytes)
    try:
        doc = json.loads(raw, parse_constant=_no_constant, parse_float=_finite_float)
    except (ValueError, RecursionError) as exc:
        raise BatchError(422, f"body is not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise BatchError(422, "batch must be a JSON object")
    if doc.get("format") != FORMAT or isinstance(doc.get("format"), bool):
        raise BatchError(422, f"format {doc.get('format')!r} is not {FORMAT}")
    unit = doc.get("unit")
    if not isinstance(unit, str) or not unit:
        raise BatchError(422, "unit must be the unit's serial")
    sent_at = None
    if doc.get("sent_at") is not None:
        sent_at = _time(doc["sent_at"], "sent_at")
    backlog = doc.get("backlog")
    if backlog is not None:
        backlog = _whole(backlog)
        if backlog is None or not 0 <= backlog <= MAX_ID:
            raise BatchError(422, f"backlog {doc['backlog']!r} is not a count of rows")
    instance = doc.get("instance")
    if instance is None or instance == "":
        instance = ""  # a vessel of a release before instances: the legacy instance
    elif not isinstance(instance, str) or not INSTANCE.fullmatch(instance):
        raise BatchError(422, f"instance {instance!r} is not a database instance id (a uuid)")
    rows = doc.get("rows")
    if not isinstance(rows, list):
        raise BatchError(422, "rows must be a list")
    return Batch(unit, sent_at, [_row(i, r) for i, r in enumerate(rows)], backlog, instance)


def content_digest(data: Any) -> str:
    """The sha256 (hex) of a row's content in canonical JSON: keys sorted, no spaces, and every
    number that a float holds exactly written as that float (``1``, ``1.0`` and ``1e0`` are the
    same content; -0.0 is 0.0). PostgreSQL's JSONB keeps neither key order nor the spelling of
    numbers, so a stored document read back and the same document as sent digest the same."""
    text = json.dumps(_canonical(data), sort_keys=True, separators=(",", ":"),
                      ensure_ascii=False, allow_nan=False)  # fmt: skip
    return hashlib.sha256(text.encode()).hexdigest()


def _canonical(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_canonical(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        try:
            as_float = float(value)
        except OverflowError:
            return value
        return as_float + 0.0 if as_float == value else value  # exact: the same number
    if isinstance(value, float):
        return value + 0.0  # -0.0 -> 0.0
    if isinstance(value, Decimal):  # a driver's reading of a JSON number
        return _canonical(int(value) if value == value.to_integral_value() else float(value))
    return value


def _row(index: int, row: Any) -> IncomingRow:
    where = f"rows[{index}]"
    if not isinstance(row, dict):
        raise BatchError(422, f"{where}: not an object")
    kind = row.get("kind")
    if not isinstance(kind, str) or kind not in _COLUMNS:  # ({} is no key: a TypeError)
        raise BatchError(422, f"{where}: kind {kind!r} is not one of {', '.join(_COLUMNS)}")
    ident = _whole(row.get("id"))
    if ident is None or not 1 <= ident <= MAX_ID:
        raise BatchError(422, f"{where}: id {row.get('id')!r} is not a vessel row id (a positive "
                         f"integer up to {MAX_ID})")  # fmt: skip
    where = f"{where} ({kind} {ident})"
    at = _time(row.get("at"), f"{where}: at")
    data = row.get("data")
    if not isinstance(data, dict):
        raise BatchError(422, f"{where}: data must be an object")
    try:
        columns = _COLUMNS[kind](ident, data)
    except ValueError as exc:
        raise BatchError(422, f"{where}: {exc}") from None
    return IncomingRow(kind, ident, at, data, columns, content_digest(data))


def _whole(value: Any) -> int | None:
    """An integer as JSON spells it (``3`` or ``3.0``: JSON Schema's integer), else None (not
    ``true``)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _time(value: Any, where: str) -> datetime:
    """An ISO 8601 time with its offset, as UTC."""
    try:
        if not isinstance(value, str):
            raise ValueError
        t = datetime.fromisoformat(value.replace("Z", "+00:00"))
    except ValueError:
        raise BatchError(422, f"{where}: {value!r} is not an ISO 8601 time") from None
    if t.tzinfo is None:
        raise BatchError(422, f"{where}: {value!r} has no UTC offset")
    try:
        return t.astimezone(UTC)
    except OverflowError:  # year 1 east of UTC, or 9999 west of it: the first or last time
        return (datetime.min if t.year == 1 else datetime.max).replace(tzinfo=UTC)


def _name(data: dict[str, Any], key: str, required: bool) -> str | None:
    value = data.get(key)
    if value is None and not required:
        return None
    if not isinstance(value, str) or not value or len(value) > MAX_NAME:
        raise ValueError(f"data.{key} must be a name of 1 to {MAX_NAME} characters")
    return value


def _version(ident: int, data: dict[str, Any]) -> dict[str, Any]:
    if "version" in data and _whole(data["version"]) != ident:
        raise ValueError(f"data.version {data['version']!r} is not the row's id")
    if not isinstance(data.get("accepted"), bool):
        raise ValueError("data.accepted must be true or false")
    return {
        "accepted": data["accepted"],
        "trigger": _name(data, "trigger", required=False),
        "method": _name(data, "method", required=False),
        "flat": flat_version(data.get("document") or {}, coefficient_names()),
        **overview_columns(data),
    }


def overview_columns(data: dict[str, Any]) -> dict[str, Any]:
    """What the overview shows of a version's document, kept in columns of its row (migration
    0008): ``heading_error_deg_rms`` (``document.navigation.after``'s, when a number) and
    ``reasons`` (when a list); None otherwise."""
    heading: Any = data
    for key in ("document", "navigation", "after", "heading_error_deg_rms"):
        heading = heading.get(key) if isinstance(heading, dict) else None
    number = isinstance(heading, int | float) and not isinstance(heading, bool)
    reasons = data.get("reasons")
    return {
        "heading_error_deg_rms": float(heading) if number else None,
        "reasons": reasons if isinstance(reasons, list) else None,
    }


def _event(ident: int, data: dict[str, Any]) -> dict[str, Any]:
    return {"kind": _name(data, "kind", required=True)}


_COLUMNS = {
    "session": lambda ident, data: {},
    "window": lambda ident, data: {},
    "slew": lambda ident, data: {},
    "version": _version,
    "event": _event,
}


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def _finite_float(text: str) -> float:
    """A JSON number as a float, refused when it overflows (``1e400`` would be infinity, which
    no column, digest or JSON answer can hold)."""
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text[:32]} is out of range for a number")
    return value
