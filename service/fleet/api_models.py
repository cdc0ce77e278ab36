"""The shore API's documented bodies (FastAPI response models): what each route of
service/fleet/api.py answers, as its OpenAPI schema states it (docs/fleet.md, "Shore REST")."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class UnitOut(BaseModel):
    unit: str = Field(description="the unit's serial")
    model: str | None
    versions: int = Field(description="calibration versions stored")
    windows: int = Field(description="static windows stored")
    current_version: int | None = Field(
        description="the newest accepted version by creation time (a rebuilt vessel's numbers "
        "start at 1 again), or null"
    )
    current_instance: str | None = Field(
        default=None, description="the vessel database instance of current_version"
    )
    last_contact: str | None = Field(description="last batch received, ISO 8601 UTC, or null")
    instance: str | None = Field(
        default=None,
        description='the vessel database instance of the latest batch ("": a vessel that '
        "sends none), or null",
    )
    conflicts: int = Field(
        default=0, description="rows received whose key was stored with other content (kept)"
    )


class ConflictOut(BaseModel):
    kind: str
    instance: str = Field(description="the vessel database instance of the batch")
    id: int = Field(description="the vessel's row id")
    at: str
    received_at: str
    digest: str = Field(description="sha256 of the row's content, canonical JSON")
    stored_digest: str = Field(description="that of the row stored under the same key")
    data: dict[str, Any] = Field(description="the row as it was received, whole")


class LinkDayOut(BaseModel):
    day: str = Field(description="UTC day, YYYY-MM-DD")
    batches: int
    rows: int = Field(description="rows received, duplicates included")
    stored: int = Field(description="rows stored (new)")
    compressed_bytes: int = Field(description="request bodies received, as sent (gzip)")


class UnitDetailOut(UnitOut):
    created_at: str | None
    rows: dict[str, int] = Field(description="rows stored per kind")
    link: list[LinkDayOut] = Field(description="the last 30 days with traffic, oldest first")
    conflict_rows: list[ConflictOut] = Field(
        default_factory=list, description="the newest 20 conflicts, newest first"
    )


class VersionOut(BaseModel):
    version: int = Field(description="the vessel's own version number")
    instance: str = Field(
        default="", description='the vessel database that made it ("": the legacy instance)'
    )
    created_at: str
    accepted: bool
    trigger: str | None
    method: str | None
    received_at: str
    document: dict[str, Any] = Field(
        description="what the vessel's GET /coefficients/{version} returns, as it was sent"
    )


class FleetVersionOut(VersionOut):
    unit: str
    model: str | None


class RowOut(BaseModel):
    id: int = Field(description="the vessel's row id")
    instance: str = Field(
        default="", description='the vessel database that made it ("": the legacy instance)'
    )
    at: str
    received_at: str
    data: dict[str, Any] = Field(description="the vessel's row as it was sent (docs/fleet.md)")


class EventRowOut(RowOut):
    kind: str


class IngestOut(BaseModel):
    stored: int = Field(description="rows stored by this batch")
    duplicates: int = Field(
        description="rows already stored with the same content (a retry), changed nothing"
    )
    conflicts: int = Field(
        default=0,
        description="rows whose key was stored with other content: kept apart, never dropped "
        "(GET /fleet/units/{unit})",
    )


class ErrorOut(BaseModel):
    """The body of every answer but 200 and a bad query parameter's 422."""

    detail: str = Field(description="what is wrong, one line")


class OutlierOut(BaseModel):
    unit: str = Field(description="the unit's serial")
    statistic: float = Field(description="sum of its squared normalised changes")
    dof: int
    p_value: float


class AgeingOut(BaseModel):
    rate: float | None = Field(description="1-sigma change after one month (null: none)")
    rate_sigma: float | None
    relative: bool = Field(description="a fraction of the value (scale factors)")
    units: int = Field(description="units behind the figure")
    changes: int = Field(description="changes (consecutive versions) behind it")


class FleetPriorOut(BaseModel):
    """A ``recal.fleet_prior/1`` document (docs/fleet.md, "The fleet prior")."""

    format: str
    version: int
    model: str
    created_at: str
    law: str
    time_unit: str
    false_alarm: float
    coefficients: dict[str, AgeingOut] = Field(description="by the conventions' flat names")
    outliers: list[OutlierOut] = Field(
        description="units set aside as outliers: every one for the administrator, the "
        "caller itself alone (if flagged) for a unit's token"
    )
    metadata: dict[str, Any]


class OutliersOut(BaseModel):
    model: str
    prior_version: int | None
    false_alarm: float | None
    outliers: list[OutlierOut] = Field(
        description="every flagged unit for the administrator; a unit's token: itself, if flagged"
    )
