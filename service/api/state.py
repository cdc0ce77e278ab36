"""What the routes need, kept on ``app.state`` by :func:`service.api.create_app` and read back
per request through these small dependencies (the routers are module-level, shared by every
app built in the process, so they must not hold any one app's parts)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request

from service.broadcast import Broadcast
from service.config import ApiSettings
from service.publish import Publisher
from service.store.repository import Store

#: ``trigger()`` queues a manual recalibration: a job id, or None / RuntimeError when it cannot.
Trigger = Callable[[], int | str | None]


def install(
    app: FastAPI,
    store: Store,
    publisher: Publisher,
    trigger: Trigger | None,
    health: Callable[[], Any] | None,
    heartbeat_s: float,
    api: ApiSettings,
) -> None:
    """Put the app's parts on ``app.state`` under the names the dependencies below read."""
    app.state.store = store
    app.state.publisher = publisher
    app.state.trigger = trigger
    app.state.trigger_lock = threading.Lock()  # one manual trigger at a time per app
    app.state.health = health
    app.state.broadcast = Broadcast(publisher, api.max_event_streams)
    app.state.heartbeat_s = heartbeat_s
    app.state.api = api


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_broadcast(request: Request) -> Broadcast:
    return request.app.state.broadcast


def get_api(request: Request) -> ApiSettings:
    return request.app.state.api


StoreDep = Annotated[Store, Depends(get_store)]
BroadcastDep = Annotated[Broadcast, Depends(get_broadcast)]
ApiDep = Annotated[ApiSettings, Depends(get_api)]
