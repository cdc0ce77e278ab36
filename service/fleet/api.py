"""The shore's HTTP API (FastAPI): ``POST /fleet/ingest`` and the fleet's REST reads.

Every route takes ``Authorization: Bearer TOKEN`` (docs/fleet.md#shore-rest): the
administrator's token (``[api] token`` of shore.toml) reads every unit; a unit's token (from
``recal fleet add-unit``) writes and reads its own unit only, and another unit answers 404 as
if absent. No token or an unknown one: 401.
"""

from __future__ import annotations

import contextlib
import hmac
import logging
from collections.abc import AsyncIterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated, Any

from fastapi import Depends, FastAPI, HTTPException, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BaseModel, Field

from recal import __version__
from service.db import StoreError
from service.fleet.batch import BatchError, read_batch
from service.fleet.config import ShoreApiSettings
from service.fleet.overview import overview as fleet_overview
from service.fleet.priors import FleetPriors
from service.fleet.store import FleetStore, Unit

log = logging.getLogger("recal.fleet")

#: Most rows one read returns; default page sizes below it.
MAX_LIMIT = 1000

_bearer = HTTPBearer(
    auto_error=False,
    description="The administrator's `[api] token` of shore.toml, or a unit's token from "
    "`recal fleet add-unit`.",
)


# ---- response models ------------------------------------------------------------------------
class UnitOut(BaseModel):
    unit: str = Field(description="the unit's serial")
    model: str | None
    versions: int = Field(description="calibration versions stored")
    windows: int = Field(description="static windows stored")
    current_version: int | None = Field(description="the newest accepted version, or null")
    last_contact: str | None = Field(description="last batch received, ISO 8601 UTC, or null")


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


class VersionOut(BaseModel):
    version: int = Field(description="the vessel's own version number")
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
    at: str
    received_at: str
    data: dict[str, Any] = Field(description="the vessel's row as it was sent (docs/fleet.md)")


class EventRowOut(RowOut):
    kind: str


class IngestOut(BaseModel):
    stored: int = Field(description="rows stored by this batch")
    duplicates: int = Field(description="rows already stored (a retry), changed nothing")


# ---- who calls --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Caller:
    """The administrator (``unit`` None) or one unit."""

    unit: Unit | None

    def sees(self, unit: Unit) -> bool:
        return self.unit is None or self.unit.id == unit.id


def _store(request: Request) -> FleetStore:
    return request.app.state.fleet_store


def caller(
    request: Request,
    credentials: HTTPAuthorizationCredentials | None = Depends(_bearer),  # noqa: B008
) -> Caller:
    """The caller of a token (401 without one, or for one that is nobody's)."""
    if credentials is not None:
        given = credentials.credentials
        admin = request.app.state.fleet_api.token
        if admin is not None and hmac.compare_digest(
            given.encode(), admin.get_secret_value().encode()
        ):
            return Caller(None)
        unit = _store(request).unit_of_token(given)
        if unit is not None:
            return Caller(unit)
    raise HTTPException(
        401, "a valid Authorization: Bearer token is required", {"WWW-Authenticate": "Bearer"}
    )


CallerDep = Annotated[Caller, Depends(caller)]
StoreDep = Annotated[FleetStore, Depends(_store)]
Limit = Annotated[int, Query(ge=1, le=MAX_LIMIT, description=f"at most this many (<= {MAX_LIMIT})")]
Since = Annotated[datetime | None, Query(description="time >= this (ISO 8601; no offset: UTC)")]
Until = Annotated[datetime | None, Query(description="time < this (ISO 8601; no offset: UTC)")]
After = Annotated[
    int | None,
    Query(ge=0, le=2**63 - 1, description="the next page: vessel row ids above this one"),
]


def _visible(store: FleetStore, who: Caller, serial: str) -> Unit:
    """The unit ``serial`` if the caller may read it; else 404, as if absent."""
    unit = store.unit_by_serial(serial)
    if unit is None or not who.sees(unit):
        raise HTTPException(404, f"no unit {serial}")
    return unit


def _utc(t: datetime | None) -> datetime | None:
    if t is None:
        return None
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


# ---- the app ----------------------------------------------------------------------------------
def create_app(store: FleetStore, api: ShoreApiSettings | None = None) -> FastAPI:
    """The shore's HTTP API over ``store``; ``api`` holds the administrator's token and the
    batch size limit."""
    from service.api.docs import add_docs

    priors = FleetPriors(store)

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        yield
        await run_in_threadpool(priors.close)  # a recompute under way finishes first

    app = FastAPI(
        lifespan=lifespan,
        title="fog-recal fleet shore service",
        version=__version__,
        description="The fleet's calibration history, as the vessels send it (docs/fleet.md). "
        "Every route needs `Authorization: Bearer <token>`: the administrator's reads every "
        "unit, a unit's reads and writes its own.",
        docs_url=None,
        redoc_url=None,
    )
    app.state.fleet_store = store
    app.state.fleet_api = api or ShoreApiSettings()
    app.state.fleet_priors = priors
    add_docs(app)
    app.add_exception_handler(StoreError, _store_unavailable)
    _routes(app)
    _fleet_routes(app)
    from service.fleet.dashboard import mount_fleet_dashboard

    mount_fleet_dashboard(app)
    return app


async def _store_unavailable(_request: Request, exc: Exception) -> JSONResponse:
    return JSONResponse(status_code=503, content={"detail": str(exc)})


async def _body(request: Request, limit: int) -> bytes:
    """The request body, refused (413) past ``limit`` bytes before it is all read."""
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise HTTPException(413, f"batch is over {limit} bytes")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise HTTPException(413, f"batch is over {limit} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


def _routes(app: FastAPI) -> None:
    @app.post(
        "/fleet/ingest",
        response_model=IngestOut,
        responses={
            401: {"description": "no token, or an unknown one"},
            403: {"description": "the token's unit is not the batch's unit"},
            413: {"description": "body over the limit"},
            422: {"description": "malformed batch; nothing of it stored"},
        },
        openapi_extra={
            "requestBody": {
                "required": True,
                "description": "a batch, format 1 (docs/fleet.md), gzip-compressed "
                "(Content-Encoding: gzip)",
                "content": {"application/json": {"schema": {"type": "object"}}},
            }
        },
    )
    async def ingest(request: Request, who: CallerDep, store: StoreDep) -> IngestOut:
        limit = request.app.state.fleet_api.max_batch_bytes
        body = await _body(request, limit)
        try:
            batch = read_batch(body, request.headers.get("content-encoding"), limit)
        except BatchError as exc:
            raise HTTPException(exc.status, str(exc)) from None
        if who.unit is None:
            raise HTTPException(403, "the administrator's token sends no batches: use the unit's")
        if batch.unit != who.unit.serial:
            raise HTTPException(403, f"this token is not unit {batch.unit}'s")
        stored, duplicates = await run_in_threadpool(store.ingest, who.unit, batch, len(body))
        if stored and any(r.kind == "version" and r.data.get("accepted") for r in batch.rows):
            # a new accepted version changes its model's prior: recomputed now, in the
            # background, so that no request waits for it
            request.app.state.fleet_priors.refresh_soon()
        log.info("%s: %d rows stored, %d duplicates (%d bytes)", who.unit.serial, stored,
                 duplicates, len(body))  # fmt: skip
        return IngestOut(stored=stored, duplicates=duplicates)

    @app.get("/fleet/units", response_model=list[UnitOut])
    def units(who: CallerDep, store: StoreDep) -> list[dict[str, Any]]:
        """Every unit, by serial (a unit's token: its own alone)."""
        return store.units(only=None if who.unit is None else who.unit.id)

    @app.get("/fleet/units/{unit}", response_model=UnitDetailOut, responses={404: {}})
    def unit(unit: str, who: CallerDep, store: StoreDep) -> dict[str, Any]:
        """One unit with its link state: rows stored, bytes and batches per day."""
        return store.unit(_visible(store, who, unit))

    @app.get("/fleet/units/{unit}/versions", response_model=list[VersionOut], responses={404: {}})
    def unit_versions(
        unit: str,
        who: CallerDep,
        store: StoreDep,
        since: Since = None,
        until: Until = None,
        after: After = None,
        limit: Limit = MAX_LIMIT,
    ) -> list[dict[str, Any]]:
        """The unit's calibration versions, oldest first (by the vessel's version number)."""
        found = _visible(store, who, unit)
        return store.rows("version", found, since=_utc(since), until=_utc(until), after=after,
                          limit=limit)  # fmt: skip

    @app.get("/fleet/units/{unit}/windows", response_model=list[RowOut], responses={404: {}})
    def unit_windows(
        unit: str,
        who: CallerDep,
        store: StoreDep,
        since: Since = None,
        until: Until = None,
        after: After = None,
        limit: Limit = 100,
    ) -> list[dict[str, Any]]:
        """The unit's static windows, oldest first (by vessel row id)."""
        found = _visible(store, who, unit)
        return store.rows("window", found, since=_utc(since), until=_utc(until), after=after,
                          limit=limit)  # fmt: skip

    @app.get("/fleet/units/{unit}/events", response_model=list[EventRowOut], responses={404: {}})
    def unit_events(
        unit: str,
        who: CallerDep,
        store: StoreDep,
        since: Since = None,
        until: Until = None,
        after: After = None,
        limit: Limit = 100,
        kind: Annotated[str | None, Query(max_length=64, description="only this kind")] = None,
    ) -> list[dict[str, Any]]:
        """The unit's events, oldest first (by vessel row id)."""
        found = _visible(store, who, unit)
        return store.rows("event", found, since=_utc(since), until=_utc(until), after=after,
                          limit=limit, event_kind=kind)  # fmt: skip

    @app.get("/fleet/versions", response_model=list[FleetVersionOut])
    def fleet_versions(
        who: CallerDep,
        store: StoreDep,
        model: Annotated[
            str | None, Query(max_length=64, description="units of this model")
        ] = None,
        accepted: bool | None = None,
        since: Since = None,
        until: Until = None,
        limit: Limit = 100,
    ) -> list[dict[str, Any]]:
        """Versions across the fleet, oldest first by creation time (a unit's token: its own)."""
        return store.fleet_versions(only=None if who.unit is None else who.unit.id, model=model,
                                    accepted=accepted, since=_utc(since), until=_utc(until),
                                    limit=limit)  # fmt: skip


# ---- what the fleet manager sees (docs/fleet.md, "The fleet dashboard") ----------------------
Model = Annotated[str, Query(min_length=1, max_length=64, description="the units' model")]


def _priors(request: Request) -> FleetPriors:
    return request.app.state.fleet_priors


PriorsDep = Annotated[FleetPriors, Depends(_priors)]


#: Response header of the fleet prior's routes: "true" when accepted versions arrived since the
#: prior answered was computed (its successor is being computed in the background).
STALE_HEADER = "X-Fleet-Prior-Stale"


def _prior_of(priors: FleetPriors, who: Caller, model: str) -> tuple[dict[str, Any], bool]:
    """The model's newest prior and whether it is stale; 404 for a model without one, or not
    the caller unit's."""
    if who.unit is not None and who.unit.model != model:
        raise HTTPException(404, f"no fleet prior for model {model}")
    documents, stale = priors.served([model])
    found = documents.get(model)
    if not found:
        raise HTTPException(
            404,
            f"no fleet prior for model {model}: it needs a unit of that model with two "
            "accepted versions",
        )
    return found, model in stale


def _fleet_routes(app: FastAPI) -> None:
    @app.get("/fleet/overview")
    def overview(who: CallerDep, store: StoreDep, priors: PriorsDep) -> dict[str, Any]:
        """One row per unit for the dashboard (units needing attention first) and the fleet's
        totals; a unit's token: its own row alone."""
        return fleet_overview(store, priors, only=None if who.unit is None else who.unit.id)

    @app.get("/fleet/prior", responses={404: {"description": "no prior for this model"}})
    def prior(who: CallerDep, priors: PriorsDep, model: Model | None = None) -> JSONResponse:
        """The model's current fleet prior, a ``recal.fleet_prior/1`` document: save it and
        point the vessel's ``[gate] fleet_prior`` at it (a vessel with ``[sync]`` fetches it
        itself). Its ``version`` rises only when the accepted versions behind it changed. A
        unit's token: its own model's, which is the default ``model``."""
        if model is None:
            if who.unit is None:
                raise HTTPException(422, "give ?model=MODEL (a unit's token defaults to its own)")
            if who.unit.model is None:
                raise HTTPException(404, f"unit {who.unit.serial} has no model registered "
                                    "(recal fleet add-unit --rotate --model MODEL)")  # fmt: skip
            model = who.unit.model
        document, stale = _prior_of(priors, who, model)
        return JSONResponse(document, headers={STALE_HEADER: "true" if stale else "false"})

    @app.get("/fleet/outliers", responses={404: {"description": "no prior for this model"}})
    def outliers(
        model: Model, who: CallerDep, priors: PriorsDep, response: Response
    ) -> dict[str, Any]:
        """The units of ``model`` whose ageing fails the fleet prior's chi-square test, with
        their statistic (a unit's token: itself, if flagged)."""
        doc, stale = _prior_of(priors, who, model)
        response.headers[STALE_HEADER] = "true" if stale else "false"
        flagged = [o for o in doc.get("outliers") or ()
                   if who.unit is None or o.get("unit") == who.unit.serial]  # fmt: skip
        return {"model": model, "prior_version": doc.get("version"),
                "false_alarm": doc.get("false_alarm"), "outliers": flagged}  # fmt: skip
