"""The shore's HTTP API (FastAPI): ``POST /fleet/ingest`` and the fleet's REST reads.

Every route takes ``Authorization: Bearer TOKEN`` (docs/fleet.md#shore-rest): the
administrator's token (``[api] token_file``, ``token_sha256`` or ``RECAL_API__TOKEN`` of the
shore's settings) reads every unit; a unit's token (from ``recal fleet add-unit``) writes and
reads its own unit only, and another unit answers 404 as if absent: nothing of another unit
reaches it (its serial, rows, statistics, whether it is an outlier; tests/fleet/test_isolation.py
walks every route). No token or an unknown one: 401. Every answer but 200 is documented with
its body (``ErrorOut``, or FastAPI's validation error for a bad query parameter).
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import AsyncIterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated, Any

import orjson
from fastapi import Depends, FastAPI, HTTPException, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BeforeValidator

from recal import __version__
from service.fleet.api_models import (
    ErrorOut,
    EventRowOut,
    FleetPriorOut,
    FleetVersionOut,
    IngestOut,
    OutliersOut,
    RowOut,
    UnitDetailOut,
    UnitOut,
    VersionOut,
)
from service.fleet.batch import FORMAT, INSTANCE, MAX_ID, MAX_NAME, BatchError, read_batch
from service.fleet.config import ShoreApiSettings
from service.fleet.overview import overview as fleet_overview
from service.fleet.priors import FleetPriors
from service.fleet.store import FleetStore, Unit
from service.store.errors import StoreError

log = logging.getLogger("recal.fleet")

#: Most rows one read returns; default page sizes below it.
MAX_LIMIT = 1000

_bearer = HTTPBearer(
    auto_error=False,
    description="The administrator's `[api] token` of shore.toml, or a unit's token from "
    "`recal fleet add-unit`.",
)


def _errors(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """The documented error answers of a route: 401 and 503 always, plus ``statuses``."""
    why = {
        401: "no token, or one that is nobody's (WWW-Authenticate: Bearer)",
        403: "the token may not do this",
        404: "absent, or not the token's unit (the same answer: another unit is never shown)",
        413: "body over [api] max_batch_bytes",
        422: "malformed: nothing of it used",
        503: "the database does not answer",
    }
    out: dict[int | str, dict[str, Any]] = {}
    for status in sorted({401, 503, *statuses}):
        out[status] = {"model": ErrorOut, "description": why[status]}
    out[401]["headers"] = {
        "WWW-Authenticate": {"schema": {"type": "string"}, "description": "Bearer"}
    }
    return out


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
        if request.app.state.fleet_api.is_admin(given):
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

#: A query time: RFC 3339, its offset optional (none: UTC)
_ISO_TIME = re.compile(
    r"(\d{4}-\d{2}-\d{2}[Tt ]\d{2}:\d{2}):(\d{2})(\.\d+)?([Zz]|[+-]\d{2}:\d{2})?"
)


def _query_time(value: Any) -> Any:
    """A query parameter's time as UTC, from RFC 3339 text alone (pydantic by itself would take
    ``0.5`` as a Unix time, which the schema does not allow); before year 1 or after 9999 in
    UTC: the first or last time there is."""
    m = _ISO_TIME.fullmatch(value) if isinstance(value, str) else None
    if m is None:
        raise ValueError("not an ISO 8601 time (YYYY-MM-DDTHH:MM:SS, its offset or Z optional)")
    head, second, fraction, offset = m.groups()
    second = min(int(second), 59)  # a leap second
    fraction = (fraction or "")[:7]  # microseconds are the finest
    text = f"{head.upper()}:{second:02d}{fraction}{(offset or '').upper().replace('Z', '+00:00')}"
    t = datetime.fromisoformat(text)  # a month 13 or hour 25: ValueError, a 422
    if t.tzinfo is None:
        return t.replace(tzinfo=UTC)
    try:
        return t.astimezone(UTC)
    except OverflowError:
        return (datetime.min if t.year == 1 else datetime.max).replace(tzinfo=UTC)


Since = Annotated[
    datetime | None,
    BeforeValidator(_query_time),
    Query(description="time >= this (ISO 8601; no offset: UTC)"),
]
Until = Annotated[
    datetime | None,
    BeforeValidator(_query_time),
    Query(description="time < this (ISO 8601; no offset: UTC)"),
]
After = Annotated[
    int | None,
    Query(ge=0, le=MAX_ID, description="the next page: vessel row ids above this one"),
]


def _visible(store: FleetStore, who: Caller, serial: str) -> Unit:
    """The unit ``serial`` if the caller may read it; else 404, as if absent (the answer does
    not repeat the serial: nothing of another unit in an answer to a unit)."""
    unit = store.unit_by_serial(serial)
    if unit is None or not who.sees(unit):
        raise HTTPException(404, "no such unit" if who.unit is not None else f"no unit {serial}")
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


def batch_schema() -> dict[str, Any]:
    """The JSON schema of an ingest batch, format 1 (docs/fleet.md, "Wire format"): what
    :func:`service.fleet.batch.read_batch` checks, no more (a body it takes is valid here, and
    one it refuses, 422, is not)."""
    time = {"type": "string", "format": "date-time", "description": "ISO 8601 with its offset"}
    name = {"type": "string", "minLength": 1, "maxLength": MAX_NAME}
    row_id = {"type": "integer", "minimum": 1, "maximum": MAX_ID,
              "description": "the vessel's row id, unique per kind"}  # fmt: skip
    data: dict[str, dict[str, Any]] = {
        "session": {"type": "object"},
        "window": {"type": "object"},
        "slew": {"type": "object"},
        "version": {
            "type": "object",
            "required": ["accepted"],
            "properties": {
                "accepted": {"type": "boolean"},
                "trigger": {"anyOf": [name, {"type": "null"}]},
                "method": {"anyOf": [name, {"type": "null"}]},
                "document": {"description": "the calibration document (conventions, section 5)"},
            },
            "description": "what the vessel's GET /coefficients/{version} returns; its "
            "`version`, when present, is the row's `id` (a rule this schema cannot spell)",
        },
        "event": {"type": "object", "required": ["kind"], "properties": {"kind": name}},
    }
    rows = [
        {
            "type": "object",
            "title": f"{kind} row",
            "required": ["kind", "id", "at", "data"],
            "properties": {"kind": {"const": kind}, "id": row_id, "at": time, "data": body},
        }
        for kind, body in data.items()
    ]
    return {
        "type": "object",
        "title": "Batch",
        "required": ["format", "unit", "rows"],
        "properties": {
            "format": {"const": FORMAT},
            "unit": {
                "type": "string",
                "minLength": 1,
                "description": "the sending unit's serial: the token's own",
            },  # fmt: skip
            "sent_at": {"anyOf": [time, {"type": "null"}]},
            "backlog": {
                "anyOf": [{"type": "integer", "minimum": 0, "maximum": MAX_ID}, {"type": "null"}],
                "description": "outbox rows the vessel still holds besides this batch",
            },
            "instance": {
                "anyOf": [
                    {"type": "string", "pattern": f"^(|{INSTANCE.pattern})$"},
                    {"type": "null"},
                ],
                "description": "the vessel database that made the rows (a uuid; absent: the "
                "legacy instance)",
            },
            "rows": {"type": "array", "items": {"oneOf": rows}},
        },
    }


def _routes(app: FastAPI) -> None:
    @app.post(
        "/fleet/ingest",
        response_model=IngestOut,
        responses=_errors(403, 413, 422)
        | {
            403: {
                "model": ErrorOut,
                "description": "the administrator's token (it sends no "
                "batches), or a token that is not the batch's unit's",
            },  # fmt: skip
            422: {
                "model": ErrorOut,
                "description": "a malformed batch (not the schema, not "
                "gzip, a bad Content-Encoding): nothing of it stored",
            },  # fmt: skip
        },
        openapi_extra={
            "requestBody": {
                "required": True,
                "description": "a batch, format 1 (docs/fleet.md), as JSON; a vessel sends it "
                "gzip-compressed with Content-Encoding: gzip (identity is taken too)",
                "content": {"application/json": {"schema": batch_schema()}},
            }
        },
    )
    async def ingest(request: Request, who: CallerDep, store: StoreDep) -> IngestOut:
        if who.unit is None:  # before reading a byte of it
            raise HTTPException(403, "the administrator's token sends no batches: use the unit's")
        limit = request.app.state.fleet_api.max_batch_bytes
        body = await _body(request, limit)
        try:
            batch = read_batch(body, request.headers.get("content-encoding"), limit)
        except BatchError as exc:
            raise HTTPException(exc.status, str(exc)) from None
        if batch.unit != who.unit.serial:
            raise HTTPException(403, "the batch's unit is not this token's")
        stored, duplicates, conflicts = await run_in_threadpool(store.ingest, who.unit, batch,
                                                                len(body))  # fmt: skip
        if stored and any(r.kind == "version" and r.data.get("accepted") for r in batch.rows):
            # a new accepted version changes its model's prior: recomputed now, in the
            # background, so that no request waits for it
            request.app.state.fleet_priors.refresh_soon()
        log.info("%s: %d rows stored, %d duplicates (%d bytes)", who.unit.serial, stored,
                 duplicates, len(body))  # fmt: skip
        if conflicts:  # a key stored with other content: kept, and said
            log.warning("%s: %d rows conflict with rows stored under the same key (instance "
                        "%r): kept in fleet_conflicts", who.unit.serial, conflicts,
                        batch.instance)  # fmt: skip
        return IngestOut(stored=stored, duplicates=duplicates, conflicts=conflicts)

    @app.get("/fleet/units", response_model=list[UnitOut], responses=_errors())
    def units(who: CallerDep, store: StoreDep) -> list[dict[str, Any]]:
        """Every unit, by serial (a unit's token: its own alone)."""
        return store.units(only=None if who.unit is None else who.unit.id)

    @app.get("/fleet/units/{unit}", response_model=UnitDetailOut, responses=_errors(404))
    def unit(unit: str, who: CallerDep, store: StoreDep) -> dict[str, Any]:
        """One unit with its link state: rows stored, bytes and batches per day."""
        return store.unit(_visible(store, who, unit))

    @app.get(
        "/fleet/units/{unit}/versions", response_model=list[VersionOut], responses=_errors(404)
    )
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

    @app.get("/fleet/units/{unit}/windows", response_model=list[RowOut], responses=_errors(404))
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

    @app.get("/fleet/units/{unit}/events", response_model=list[EventRowOut], responses=_errors(404))
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

    @app.get("/fleet/versions", response_model=list[FleetVersionOut], responses=_errors())
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
_STALE_DOC = {
    STALE_HEADER: {
        "schema": {"type": "string", "enum": ["true", "false"]},
        "required": True,
        "description": "true: accepted versions arrived since this prior was computed (its "
        "successor is being computed)",
    }
}


def _own_view(document: dict[str, Any], who: Caller) -> dict[str, Any]:
    """The prior as ``who`` may see it: the model's aggregate figures, and of the outliers
    every one for the administrator, the unit itself alone (if flagged) for a unit."""
    if who.unit is None:
        return document
    mine = [o for o in document.get("outliers") or () if o.get("unit") == who.unit.serial]
    return {**document, "outliers": mine}


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
    return _own_view(found, who), model in stale


def _fleet_routes(app: FastAPI) -> None:
    @app.get("/fleet/overview", response_model=dict[str, Any], responses=_errors())
    def overview(who: CallerDep, store: StoreDep, priors: PriorsDep) -> JSONResponse:
        """One row per unit for the dashboard (units needing attention first) and the fleet's
        totals; a unit's token: its own row alone."""
        # JSON values only: encoded as they are, without a pass of the response model over
        # the whole answer first, by orjson (1.2 MB at 1000 units: 1 ms, the standard
        # library's 17 ms; docs/fleet.md#scale); a non-finite number becomes null
        view = fleet_overview(store, priors, only=None if who.unit is None else who.unit.id)
        return Response(orjson.dumps(view), media_type="application/json")

    @app.get(
        "/fleet/prior",
        response_model=None,
        responses={200: {"model": FleetPriorOut, "headers": _STALE_DOC}}
        | _errors(404)
        | {
            404: {
                "model": ErrorOut,
                "description": "no prior for this model yet, another "
                "unit's model, or no model: the administrator's token needs ?model=",
            }
        },  # fmt: skip
    )
    def prior(who: CallerDep, priors: PriorsDep, model: Model | None = None) -> JSONResponse:
        """The model's current fleet prior, a ``recal.fleet_prior/1`` document: save it and
        point the vessel's ``[gate] fleet_prior`` at it (a vessel with ``[sync]`` fetches it
        itself). Its ``version`` rises only when the accepted versions behind it changed. A
        unit's token: its own model's, which is the default ``model``, with its own outlier
        status alone (no other unit's)."""
        if model is None:
            if who.unit is None:
                raise HTTPException(404, "the administrator has no model of its own: give "
                                    "?model=MODEL")  # fmt: skip
            if who.unit.model is None:
                raise HTTPException(404, f"unit {who.unit.serial} has no model registered "
                                    "(recal fleet add-unit --rotate --model MODEL)")  # fmt: skip
            model = who.unit.model
        document, stale = _prior_of(priors, who, model)
        return JSONResponse(document, headers={STALE_HEADER: "true" if stale else "false"})

    @app.get(
        "/fleet/outliers",
        response_model=OutliersOut,
        responses={200: {"headers": _STALE_DOC}} | _errors(404),
    )
    def outliers(
        model: Model, who: CallerDep, priors: PriorsDep, response: Response
    ) -> dict[str, Any]:
        """The units of ``model`` whose ageing fails the fleet prior's chi-square test, with
        their statistic (a unit's token: itself, if flagged)."""
        doc, stale = _prior_of(priors, who, model)  # a unit's: its own outlier status alone
        response.headers[STALE_HEADER] = "true" if stale else "false"
        return {"model": model, "prior_version": doc.get("version"),
                "false_alarm": doc.get("false_alarm"), "outliers": doc.get("outliers") or []}  # fmt: skip
