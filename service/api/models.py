"""The API's response models and the request bounds the routes share."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from fastapi import Path
from pydantic import BaseModel

from service.store.records import CalibrationRecord

#: Largest id or version a request may name: the schema's INTEGER columns are 32-bit signed
#: on PostgreSQL (a larger value there is a database error, not a missing row).
MAX_DB_INT = 2**31 - 1

DbId = Annotated[int, Path(ge=1, le=MAX_DB_INT)]


class _VersionOut(BaseModel):
    """What every listing of a stored calibration shows."""

    version: int
    created_at: datetime
    trigger: str
    method: str
    accepted: bool
    reasons: list[str]
    prior_version: int | None


class CalibrationOut(_VersionOut):
    """A stored calibration; ``document`` is the ``recal calibrate --json`` object."""

    document: dict[str, Any]
    positions_used: list[int]

    @classmethod
    def of(cls, record: CalibrationRecord) -> CalibrationOut:
        assert record.version is not None  # records read back from the Store have one
        return cls(
            version=record.version,
            created_at=record.created_at,
            trigger=record.trigger,
            method=record.method,
            accepted=record.accepted,
            reasons=record.reasons,
            document=record.document,
            positions_used=record.positions_used,
            prior_version=record.prior_version,
        )


class CalibrationSummaryOut(_VersionOut):
    """One line of the history: the record without its document, plus its key figures."""

    positions: int | None
    chi2_red: float | None
    verdict: str | None
    sensor: str | None


class DayTrafficOut(BaseModel):
    day: str  # YYYY-MM-DD, UTC
    bytes: int  # sent, compressed, every attempt
    rows: int  # acknowledged by the shore


class SyncOut(BaseModel):
    """The fleet link (docs/fleet.md)."""

    state: str  # off (no [sync] section), up, down, rejected (the shore refuses: see last_error)
    url: str | None
    unit: str | None
    backlog: int | None  # outbox rows still to send (None: the database does not answer)
    last_contact: str | None  # when the shore last answered, ISO 8601 UTC
    last_error: str | None
    bytes_today: int
    bytes_per_day: list[DayTrafficOut]  # the last 7 UTC days, oldest first


class HealthOut(BaseModel):
    status: str  # "ok", or "degraded" with the reasons in ``problems``
    problems: list[str]
    positions: int
    current_version: int | None
    sync: SyncOut
    service: Any  # the parts' own state: reader, detector, scheduler, publisher, spool


class EventOut(BaseModel):
    id: int
    created_at: str
    kind: str
    message: str
    data: Any


class QueuedOut(BaseModel):
    queued: bool
    job: int | str
