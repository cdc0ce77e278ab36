"""The REST and Server-Sent Events API over the Store and the Publisher (FastAPI).

``create_app(store, publisher, trigger, health)`` builds the app; the daemon serves it with
uvicorn. ``trigger()`` queues a manual recalibration and returns a job id; it returns None or
raises RuntimeError (e.g. ``pipeline.SchedulerBusy``) when it cannot start one (409). SSE streams
end when the client goes or when :meth:`Publisher.close` is called: call it as shutdown begins,
since uvicorn waits for open streams before it shuts the app down.
"""

from __future__ import annotations

import json
import math
import queue
import time
from collections.abc import AsyncIterator, Callable
from datetime import datetime
from typing import Annotated, Any

import anyio
from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.responses import JSONResponse
from fastapi.sse import EventSourceResponse, ServerSentEvent
from pydantic import BaseModel

from recal import __version__
from service.db import CalibrationRecord, Store, StoreError
from service.publish import Publisher

#: How often an idle SSE stream checks its queue and the client (seconds).
_POLL_S = 0.1


class CalibrationOut(BaseModel):
    """A stored calibration; ``document`` is the ``recal calibrate --json`` object."""

    version: int
    created_at: datetime
    trigger: str
    method: str
    accepted: bool
    reasons: list[str]
    document: dict[str, Any]
    positions_used: list[int]
    prior_version: int | None

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


class HealthOut(BaseModel):
    status: str
    reader: Any
    positions: int
    current_version: int | None


class QueuedOut(BaseModel):
    queued: bool
    job: int | str


def create_app(
    store: Store,
    publisher: Publisher,
    trigger: Callable[[], int | str | None] | None = None,
    health: Callable[[], Any] | None = None,
    heartbeat_s: float = 15.0,
) -> FastAPI:
    """The service's HTTP API; OpenAPI docs at ``/docs``."""
    app = FastAPI(
        title="fog-recal onboard service",
        version=__version__,
        description="Current and past IMU calibrations, stored positions, manual triggers and "
        "a live feed of published coefficients.",
    )

    @app.exception_handler(StoreError)
    async def store_unavailable(_request: Request, exc: StoreError) -> JSONResponse:
        return JSONResponse(status_code=503, content={"detail": str(exc)})

    @app.get("/health", response_model=HealthOut)
    def get_health() -> HealthOut:
        current = store.current()
        return HealthOut(
            status="ok",
            reader=health() if health is not None else None,
            positions=store.count_positions(),
            current_version=None if current is None else current.version,
        )

    @app.get("/coefficients", response_model=CalibrationOut, responses={404: {}})
    def get_current() -> CalibrationOut:
        record = store.current()
        if record is None:
            raise HTTPException(404, "no accepted calibration yet")
        return CalibrationOut.of(record)

    @app.get("/coefficients/history", response_model=list[CalibrationOut])
    def get_history(limit: Annotated[int, Query(ge=1, le=1000)] = 50) -> list[CalibrationOut]:
        return [CalibrationOut.of(r) for r in store.history(limit)]

    @app.get("/coefficients/{version}", response_model=CalibrationOut, responses={404: {}})
    def get_version(version: int) -> CalibrationOut:
        record = store.calibration(version)
        if record is None:
            raise HTTPException(404, f"no calibration version {version}")
        return CalibrationOut.of(record)

    @app.get("/positions")
    def get_positions(
        limit: Annotated[int, Query(ge=1, le=100_000)] = 1000,
        since_id: Annotated[int | None, Query(ge=0)] = None,
    ) -> list[dict[str, float | int | None]]:
        """Stored positions in id order (the first ``limit`` after ``since_id``), one object
        per row: ``id`` and the columns common to the rows (NaN as null)."""
        table, ids = store.positions(since_id=since_id, limit=limit)
        names = list(table.columns)
        return [
            {"id": pid} | {n: _finite(table.columns[n][i]) for n in names}
            for i, pid in enumerate(ids)
        ]

    @app.post(
        "/recalibrate",
        status_code=202,
        response_model=QueuedOut,
        responses={
            409: {"description": "a job is running or cannot start"},
            503: {"description": "no trigger"},
        },
    )
    def post_recalibrate() -> QueuedOut:
        if trigger is None:
            raise HTTPException(503, "manual recalibration is not available in this service")
        try:
            job = trigger()
        except RuntimeError as exc:  # busy, or the scheduler is shutting down
            raise HTTPException(409, str(exc) or "a recalibration cannot start now") from None
        if job is None:
            raise HTTPException(409, "a recalibration is already running")
        return QueuedOut(queued=True, job=job)

    @app.get("/events", response_class=EventSourceResponse)
    async def get_events(request: Request) -> AsyncIterator[ServerSentEvent]:
        """Server-Sent Events: ``event: coefficients`` with the published JSON as ``data``,
        a comment heartbeat when idle."""
        sub = publisher.subscribe()
        try:
            # Tells the client the subscription exists: nothing published from now on is missed.
            yield ServerSentEvent(comment="subscribed")
            last_sent = time.monotonic()
            while True:
                try:
                    item = sub.get_nowait()
                except queue.Empty:
                    if await request.is_disconnected():
                        return
                    if time.monotonic() - last_sent >= heartbeat_s:
                        yield ServerSentEvent(comment="heartbeat")
                        last_sent = time.monotonic()
                    await anyio.sleep(_POLL_S)
                    continue
                if item is None:  # the publisher closed: the service is stopping
                    return
                yield ServerSentEvent(
                    event="coefficients", id=str(item["version"]), raw_data=json.dumps(item)
                )
                last_sent = time.monotonic()
        finally:
            publisher.unsubscribe(sub)

    return app


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None
