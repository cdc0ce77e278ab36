"""The REST and Server-Sent Events API over the Store and the Publisher (FastAPI).

``create_app(store, publisher, trigger, health, api=settings.api)`` builds the app; the daemon
serves it with uvicorn. ``trigger()`` queues a manual recalibration and returns a job id; it
returns None or raises RuntimeError (e.g. ``scheduler.SchedulerBusy``) when it cannot start one
(409, with the reason). SSE streams end when the client goes or when :meth:`Publisher.close` is
called: call it as shutdown begins, since uvicorn waits for open streams before it shuts down.

One module per resource, each an ``APIRouter`` that reads the app's parts from ``app.state``
(:mod:`service.api.state`): :mod:`~service.api.health` (``/health``, ``/log``),
:mod:`~service.api.coefficients`, :mod:`~service.api.positions`,
:mod:`~service.api.recalibrate`, :mod:`~service.api.events` (``/events``); the response models
in :mod:`~service.api.models`, the token and origin checks in :mod:`~service.api.security`
(docs/reference.md#api), the offline ``/docs`` page in :mod:`~service.api.docs`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from recal import __version__
from service.api import coefficients, events, health, positions, recalibrate, state
from service.api.docs import add_docs
from service.api.models import (
    MAX_DB_INT,
    CalibrationOut,
    CalibrationSummaryOut,
    EventOut,
    HealthOut,
    QueuedOut,
)
from service.api.security import OriginGuard, add_origin_guard, request_refusal
from service.config import ApiSettings
from service.dashboard import mount_dashboard
from service.publish import Publisher
from service.store.errors import StoreError
from service.store.repository import Store

__all__ = [
    "MAX_DB_INT",
    "CalibrationOut",
    "CalibrationSummaryOut",
    "EventOut",
    "HealthOut",
    "OriginGuard",
    "QueuedOut",
    "create_app",
    "request_refusal",
]

#: The resource routers, in the order their routes are matched.
ROUTERS = (health.router, coefficients.router, positions.router, recalibrate.router, events.router)


def create_app(
    store: Store,
    publisher: Publisher,
    trigger: state.Trigger | None = None,
    health: Callable[[], Any] | None = None,
    heartbeat_s: float = 15.0,
    api: ApiSettings | None = None,
) -> FastAPI:
    """The service's HTTP API; documentation at ``/docs``. ``api`` holds the token, the
    allowed origins and the stream cap (defaults: no token, so no writes); ``heartbeat_s`` is
    the idle time (s) after which an ``/events`` stream sends a comment."""
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
    state.install(app, store, publisher, trigger, health, heartbeat_s, api)
    add_docs(app)
    add_origin_guard(app, api.allowed_origins)
    mount_dashboard(app, store)  # the operator's page at /
    app.add_exception_handler(StoreError, _store_unavailable)
    for router in ROUTERS:
        app.include_router(router)
    return app


async def _store_unavailable(_request: Request, exc: Exception) -> JSONResponse:
    """A database that does not answer is the service being unavailable, not a bug (503)."""
    return JSONResponse(status_code=503, content={"detail": str(exc)})
