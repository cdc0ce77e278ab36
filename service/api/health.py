"""``/health`` (ok or degraded, with the reasons) and ``/log`` (the service's events)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request

from service.api.models import EventOut, HealthOut
from service.api.state import StoreDep
from service.store.errors import StoreError
from service.sync.stats import off_block

router = APIRouter()


@router.get("/health", response_model=HealthOut)
def get_health(request: Request, store: StoreDep) -> HealthOut:
    """``ok``, or ``degraded`` with the reasons (device lost, database down, publish file
    unwritable, job supervisor gone, the shore refusing this unit); the parts' state in
    ``service``; the fleet link in ``sync`` (``off`` without a ``[sync]`` section)."""
    health = request.app.state.health
    parts = health() if health is not None else {}
    parts = dict(parts) if isinstance(parts, dict) else {}
    problems = list(parts.get("problems", []))
    sync = parts.pop("sync", None)  # its own block
    try:
        current = store.current()
        positions = store.count_positions()
        if sync is None:
            sync = off_block(store.outbox_count())
    except StoreError as exc:  # /health must answer while the database is down
        current, positions = None, -1
        problems.append(f"database: {exc}")
    return HealthOut(
        status="degraded" if problems else "ok",
        problems=problems,
        positions=positions,
        current_version=None if current is None else current.version,
        sync=sync if sync is not None else off_block(None),
        service=parts,
    )


@router.get("/log", response_model=list[EventOut])
def get_log(store: StoreDep, limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[EventOut]:
    """The service's events, newest first: windows stored, jobs started, ended or failed
    with the reason, versions accepted or rejected, publications, database and device
    trouble (the same lines the log shows)."""
    return [EventOut(**e) for e in store.events(limit)]
