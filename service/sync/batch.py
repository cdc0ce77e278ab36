"""Building one batch (docs/fleet.md, format 1): the oldest outbox rows, the rows they name in
the wire format, JSON, gzip.

A batch holds at most ``max_rows`` rows and about ``max_json_bytes`` of JSON before
compression (one row alone may exceed it); the outbox rows it *settles* are those whose rows
it carries plus those whose rows are no longer stored (nothing to send: they go with the
batch's acknowledgement).
"""

from __future__ import annotations

import gzip
import json
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from service.store.codec import plain

#: The wire format's version (docs/fleet.md).
FORMAT = 1
#: Most rows a batch holds.
MAX_ROWS = 500
#: About the most JSON a batch holds before compression, bytes.
MAX_JSON_BYTES = 256 * 1024


def iso_utc(at: datetime) -> str:
    """ISO 8601 in UTC with a ``Z``: ``2026-11-26T12:00:00Z`` (microseconds when present)."""
    when = at.replace(tzinfo=UTC) if at.tzinfo is None else at.astimezone(UTC)
    return when.isoformat().replace("+00:00", "Z")


@dataclass
class Batch:
    """One request's worth: the gzip body, and what its acknowledgement settles."""

    body: bytes
    json_bytes: int
    rows: list[tuple[str, int]] = field(default_factory=list)  # (kind, id), in order
    settles: list[int] = field(default_factory=list)  # outbox seq numbers
    #: More rows may wait in the outbox (the batch is full): send the next one at once.
    more: bool = False

    def name_row(self, index: int) -> str:
        """``window 1234`` for the row at ``index`` of ``rows`` (``row N`` if out of range)."""
        if 0 <= index < len(self.rows):
            kind, ref = self.rows[index]
            return f"{kind} {ref}"
        return f"row {index}"

    def describe(self) -> str:
        """``12 rows: window 1..12`` style summary for messages."""
        if not self.rows:
            return "no rows"
        kinds: dict[str, list[int]] = {}
        for kind, ref in self.rows:
            kinds.setdefault(kind, []).append(ref)
        parts = [f"{k} {min(v)}" + (f"..{max(v)}" if len(v) > 1 else "") for k, v in kinds.items()]
        return f"{len(self.rows)} row{'s' if len(self.rows) != 1 else ''}: {', '.join(parts)}"


def build(
    store: Any,
    unit: str,
    *,
    max_rows: int = MAX_ROWS,
    max_json_bytes: int = MAX_JSON_BYTES,
    now: datetime | None = None,
) -> Batch | None:
    """The next batch from ``store``'s outbox (None when the outbox is empty)."""
    entries = store.outbox(max_rows)
    if not entries:
        return None
    found = store.outbox_rows(entries)
    encoded: list[str] = []
    batch = Batch(body=b"", json_bytes=0)
    size = 0
    for entry in entries:
        key = (entry.kind, entry.ref_id)
        stored = found.get(key)
        if stored is None:  # deleted since: nothing to send, settled with the batch
            batch.settles.append(entry.seq)
            continue
        text = json.dumps(wire_row(entry.kind, entry.ref_id, stored), separators=(",", ":"),
                          allow_nan=False)  # fmt: skip
        if encoded and size + len(text) + 1 > max_json_bytes:
            batch.more = True
            break
        encoded.append(text)
        size += len(text) + 1
        batch.rows.append(key)
        batch.settles.append(entry.seq)
    batch.more = batch.more or len(entries) >= max_rows
    sent_at = iso_utc(now or datetime.now(UTC))
    # what the vessel still holds besides this batch: the shore shows the link's backlog
    backlog = max(0, store.outbox_count() - len(batch.settles))
    header: dict[str, Any] = {"format": FORMAT, "unit": unit, "sent_at": sent_at,
                              "backlog": backlog}  # fmt: skip
    instance = store.instance()  # which database made the rows: their ids are its own
    if instance:
        header["instance"] = instance
    head = json.dumps(header, separators=(",", ":"))
    document = f'{head[:-1]},"rows":[{",".join(encoded)}]}}'.encode()
    batch.json_bytes = len(document)
    batch.body = gzip.compress(document, compresslevel=6, mtime=0)
    return batch


def wire_row(kind: str, ref_id: int, stored: dict[str, Any]) -> dict[str, Any]:
    """One row of a batch: ``kind``, ``id``, ``at`` and ``data`` (docs/fleet.md's table)."""
    return {"kind": kind, "id": ref_id, "at": iso_utc(stored["at"]),
            "data": plain(_DATA[kind](stored))}  # fmt: skip


def _session(stored: dict[str, Any]) -> dict[str, Any]:
    return {"source": stored["source"], "meta": stored["meta"],
            "started_at": iso_utc(stored["at"])}  # fmt: skip


def _window(stored: dict[str, Any]) -> dict[str, Any]:
    return {**stored["columns"], "session": stored["session"]}


def _slew(stored: dict[str, Any]) -> dict[str, Any]:
    r = stored["slew"]
    groups = None
    if r.groups is not None:
        counts, S, W, C = r.groups
        groups = {"count": counts, "S": S, "W": W, "C": C}
    return {"first_id": r.first_id, "second_id": r.second_id, "period_s": r.period_s,
            "samples": r.samples, "reference": r.reference, "groups": groups,
            "dropped": r.dropped}  # fmt: skip


def _version(stored: dict[str, Any]) -> dict[str, Any]:
    # exactly the vessel's GET /coefficients/{version} document
    from service.api.models import CalibrationOut

    return CalibrationOut.of(stored["record"]).model_dump(mode="json")


def _event(stored: dict[str, Any]) -> dict[str, Any]:
    return {"kind": stored["kind"], "message": stored["message"], "data": stored["data"],
            "created_at": iso_utc(stored["at"])}  # fmt: skip


_DATA = {"session": _session, "window": _window, "slew": _slew, "version": _version,
         "event": _event}  # fmt: skip
