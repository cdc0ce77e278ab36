"""The REST and Server-Sent Events API over the Store and the Publisher (FastAPI).

``create_app(store, publisher, trigger, health, api=settings.api)`` builds the app; the daemon
serves it with uvicorn. ``trigger()`` queues a manual recalibration and returns a job id; it
returns None or raises RuntimeError (e.g. ``scheduler.SchedulerBusy``) when it cannot start one
(409, with the reason). SSE streams end when the client goes or when :meth:`Publisher.close` is
called: call it as shutdown begins, since uvicorn waits for open streams before it shuts down.

Security (docs/reference.md#api): write endpoints need ``Authorization: Bearer <[api] token>``
and are refused while no token is configured; requests carrying a foreign ``Origin`` are refused
unless it is listed in ``[api] allowed_origins``, and writes with a body type a plain HTML form
can send are refused, so a web page open on a bridge computer cannot trigger anything. At most
``[api] max_event_streams`` ``/events`` streams are open at once (429 beyond). The
documentation page at ``/docs`` loads Swagger UI from the installed ``swagger-ui-bundle-v2``
package, so it works without internet access.
"""

from __future__ import annotations

import hmac
import json
import math
import threading
from collections.abc import AsyncIterator, Callable
from datetime import datetime
from typing import Annotated, Any

from fastapi import Depends, FastAPI, HTTPException, Path, Query, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.sse import EventSourceResponse, ServerSentEvent
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel
from starlette.middleware.cors import CORSMiddleware
from starlette.types import ASGIApp, Receive, Scope, Send

from recal import __version__
from service.broadcast import TIMEOUT, Broadcast, Stream, TooManyStreams
from service.config import ApiSettings
from service.dashboard import mount_dashboard
from service.db import CalibrationRecord, Store, StoreError
from service.publish import Publisher

#: Largest id or version a request may name: the schema's INTEGER columns are 32-bit signed
#: on PostgreSQL (a larger value there is a database error, not a missing row).
MAX_DB_INT = 2**31 - 1
#: Largest page of whole records from ``/coefficients/history?full=true``.
MAX_FULL_HISTORY = 100
#: Methods that change something; they need the token and a non-form body.
WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: Body types a browser sends cross-origin without asking first ("simple requests").
FORM_CONTENT_TYPES = frozenset(
    {"text/plain", "application/x-www-form-urlencoded", "multipart/form-data"}
)
_DOCS_ASSETS = "/docs-assets"

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


class HealthOut(BaseModel):
    status: str  # "ok", or "degraded" with the reasons in ``problems``
    problems: list[str]
    positions: int
    current_version: int | None
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


def create_app(
    store: Store,
    publisher: Publisher,
    trigger: Callable[[], int | str | None] | None = None,
    health: Callable[[], Any] | None = None,
    heartbeat_s: float = 15.0,
    api: ApiSettings | None = None,
) -> FastAPI:
    """The service's HTTP API; documentation at ``/docs``. ``api`` holds the token, the
    allowed origins and the stream cap (defaults: no token, so no writes).

    Dependencies are given as default values: the annotations are strings (``from __future__
    import annotations``) that cannot name this function's locals.
    """
    api = api or ApiSettings()
    app = FastAPI(
        title="fog-recal onboard service",
        version=__version__,
        description="Current and past IMU calibrations, stored positions, manual triggers and "
        "a live feed of published coefficients. Write endpoints need "
        "`Authorization: Bearer <token>` (the `[api] token` setting).",
        docs_url=None,
        redoc_url=None,
    )
    app.state.broadcast = broadcast = Broadcast(publisher, api.max_event_streams)
    require_token = _token_checker(api)
    _add_docs(app)
    _add_origin_guard(app, api.allowed_origins)
    mount_dashboard(app, store)  # the operator's page at /

    @app.exception_handler(StoreError)
    async def store_unavailable(_request: Request, exc: StoreError) -> JSONResponse:
        return JSONResponse(status_code=503, content={"detail": str(exc)})

    @app.get("/health", response_model=HealthOut)
    def get_health() -> HealthOut:
        """``ok``, or ``degraded`` with the reasons (device lost, database down, publish file
        unwritable, job supervisor gone); the parts' state in ``service``."""
        parts = health() if health is not None else {}
        problems = list(parts.get("problems", [])) if isinstance(parts, dict) else []
        try:
            current = store.current()
            positions = store.count_positions()
        except StoreError as exc:  # /health must answer while the database is down
            current, positions = None, -1
            problems.append(f"database: {exc}")
        return HealthOut(
            status="degraded" if problems else "ok",
            problems=problems,
            positions=positions,
            current_version=None if current is None else current.version,
            service=parts,
        )

    @app.get("/log", response_model=list[EventOut])
    def get_log(limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[EventOut]:
        """The service's events, newest first: windows stored, jobs started, ended or failed
        with the reason, versions accepted or rejected, publications, database and device
        trouble (the same lines the log shows)."""
        return [EventOut(**e) for e in store.events(limit)]

    @app.get("/coefficients", response_model=CalibrationOut, responses={404: {}})
    def get_current() -> CalibrationOut:
        record = store.current()
        if record is None:
            raise HTTPException(404, "no accepted calibration yet")
        return CalibrationOut.of(record)

    @app.get(
        "/coefficients/history",
        response_model=list[CalibrationSummaryOut] | list[CalibrationOut],
        responses={422: {"description": "bad paging parameters"}},
    )
    def get_history(
        limit: Annotated[int, Query(ge=1, le=1000)] = 50,
        before_version: Annotated[int | None, Query(ge=1, le=MAX_DB_INT)] = None,
        full: bool = False,
    ) -> list[CalibrationSummaryOut] | list[CalibrationOut]:
        """Calibrations, accepted or not, newest first: summaries (version, time, accepted,
        reasons, key figures), or whole records with ``full=true`` (then at most 100 a page,
        whatever ``limit`` says).
        The next page is ``before_version=<the last version listed>``."""
        if not full:
            return [
                CalibrationSummaryOut(**s) for s in store.history_summaries(limit, before_version)
            ]
        records = _full_history(store, min(limit, MAX_FULL_HISTORY), before_version)
        return [CalibrationOut.of(r) for r in records]

    @app.get("/coefficients/{version}", response_model=CalibrationOut, responses={404: {}})
    def get_version(version: DbId) -> CalibrationOut:
        record = store.calibration(version)
        if record is None:
            raise HTTPException(404, f"no calibration version {version}")
        return CalibrationOut.of(record)

    @app.get("/positions")
    def get_positions(
        limit: Annotated[int, Query(ge=1, le=100_000)] = 1000,
        since_id: Annotated[int | None, Query(ge=0, le=MAX_DB_INT)] = None,
    ) -> list[dict[str, float | int | None]]:
        """Stored positions in id order (the first ``limit`` after ``since_id``), one object
        per row: ``id`` and the columns common to the rows (NaN as null)."""
        table, ids = store.positions(since_id=since_id, limit=limit)
        names = list(table.columns)
        return [
            {"id": pid} | {n: _finite(table.columns[n][i]) for n in names}
            for i, pid in enumerate(ids)
        ]

    trigger_lock = threading.Lock()

    @app.post(
        "/recalibrate",
        status_code=202,
        response_model=QueuedOut,
        dependencies=[Depends(require_token)],
        responses={
            401: {"description": "no or wrong bearer token"},
            403: {"description": "no token is configured, or a foreign origin"},
            409: {"description": "a job is queued or running, or cannot start (the reason)"},
            415: {"description": "a form or text body"},
            503: {"description": "no trigger"},
        },
    )
    def post_recalibrate() -> QueuedOut:
        """Queue a recalibration on the stored positions (needs the bearer token)."""
        if trigger is None:
            raise HTTPException(503, "manual recalibration is not available in this service")
        with trigger_lock:  # concurrent requests: one queues a job, the others hear why not
            try:
                job = trigger()
            except RuntimeError as exc:  # busy, or the scheduler is shutting down
                raise HTTPException(409, str(exc) or "a recalibration cannot start now") from None
        if job is None:
            raise HTTPException(409, "a recalibration is already running")
        return QueuedOut(queued=True, job=job)

    async def event_stream() -> Stream:
        try:
            return broadcast.open()
        except TooManyStreams as exc:
            raise HTTPException(429, f"{exc}: try again later", {"Retry-After": "30"}) from None

    @app.get(
        "/events",
        response_class=EventSourceResponse,
        responses={429: {"description": "too many open streams ([api] max_event_streams)"}},
    )
    async def get_events(
        stream: Stream = Depends(event_stream),  # noqa: B008
    ) -> AsyncIterator[ServerSentEvent]:
        """Server-Sent Events: ``event: coefficients`` with the published JSON as ``data``
        (the current version first, if any), a comment heartbeat when idle."""
        # The slot is freed here when the stream ends or the client goes (FastAPI ends a yield
        # dependency before the stream), and by the Broadcast if this never starts.
        try:
            # Tells the client the subscription exists: nothing published from now on is missed.
            yield ServerSentEvent(comment="subscribed")
            sent: Any = None
            while True:
                item = await stream.next(heartbeat_s)
                if item is TIMEOUT:
                    yield ServerSentEvent(comment="heartbeat")
                    continue
                if item is None:  # the publisher closed: the service is stopping
                    return
                if item.get("version") == sent:  # handed over twice around subscription time
                    continue
                sent = item.get("version")
                yield ServerSentEvent(event="coefficients", id=str(sent), raw_data=json.dumps(item))
        finally:
            broadcast.close(stream)

    return app


def _full_history(store: Store, limit: int, before_version: int | None) -> list[CalibrationRecord]:
    """Whole records for one history page (the summaries give the versions)."""
    if before_version is None:
        return store.history(limit)
    versions = [s["version"] for s in store.history_summaries(limit, before_version)]
    records = (store.calibration(v) for v in versions)
    return [r for r in records if r is not None]


def _token_checker(api: ApiSettings) -> Callable[..., None]:
    """A dependency that refuses requests without ``Authorization: Bearer <api.token>``."""
    bearer = HTTPBearer(
        auto_error=False,
        description="The `[api] token` setting (or the RECAL_API__TOKEN environment variable).",
    )
    expected = None if api.token is None else api.token.get_secret_value().encode()

    def require_token(credentials: HTTPAuthorizationCredentials | None = Depends(bearer)) -> None:  # noqa: B008
        if expected is None:
            raise HTTPException(
                403, "write endpoints are disabled: no [api] token is configured on the service"
            )
        given = b"" if credentials is None else credentials.credentials.encode()
        if not hmac.compare_digest(given, expected):  # constant time
            raise HTTPException(
                401,
                "a valid Authorization: Bearer token is required",
                {"WWW-Authenticate": "Bearer"},
            )

    return require_token


def _add_docs(app: FastAPI) -> None:
    """``/docs`` from the packaged Swagger UI (no CDN: the page works offline)."""
    from swagger_ui_bundle import swagger_ui_path

    app.mount(_DOCS_ASSETS, StaticFiles(directory=str(swagger_ui_path)), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    def docs(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        return get_swagger_ui_html(
            openapi_url=f"{root}{app.openapi_url}",
            title=f"{app.title} - API",
            swagger_js_url=f"{root}{_DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{root}{_DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{root}{_DOCS_ASSETS}/favicon-32x32.png",
            oauth2_redirect_url=None,
        )


def _add_origin_guard(app: FastAPI, allowed: list[str]) -> None:
    if allowed:  # answers the browsers' preflight for the configured origins
        app.add_middleware(
            CORSMiddleware,
            allow_origins=allowed,
            allow_methods=["GET", "POST"],
            allow_headers=["Authorization", "Content-Type", "Last-Event-ID"],
        )
    app.add_middleware(OriginGuard, allowed=frozenset(allowed))  # added last: runs first


class OriginGuard:
    """ASGI middleware: refuse cross-origin requests from origins not allowed (403) and write
    requests whose body type a plain HTML form can send (415)."""

    def __init__(self, app: ASGIApp, allowed: frozenset[str]) -> None:
        self.app = app
        self.allowed = allowed

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            refusal = request_refusal(scope, self.allowed)
            if refusal is not None:
                status, detail = refusal
                await JSONResponse({"detail": detail}, status)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def request_refusal(scope: Scope, allowed: frozenset[str]) -> tuple[int, str] | None:
    """Why an HTTP request is refused by :class:`OriginGuard`, or None."""
    headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
    origin = headers.get("origin")
    if origin is not None and not _same_origin(origin, scope, headers):
        if origin.lower() not in allowed:
            return 403, f"cross-origin request from {origin} refused ([api] allowed_origins)"
    if scope["method"] in WRITE_METHODS:
        media = headers.get("content-type", "").split(";")[0].strip().lower()
        if media in FORM_CONTENT_TYPES:
            return 415, f"a {media} body is not accepted here: send no body or application/json"
    return None


def _same_origin(origin: str, scope: Scope, headers: dict[str, str]) -> bool:
    """The page comes from this very server (e.g. the ``/docs`` page)."""
    host = headers.get("host")
    return host is not None and origin.lower() == f"{scope.get('scheme', 'http')}://{host}".lower()


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None
