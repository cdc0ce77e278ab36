"""``/events``: Server-Sent Events of the published coefficients, at most
``[api] max_event_streams`` streams at once (429 beyond)."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.sse import EventSourceResponse, ServerSentEvent

from service.api.state import BroadcastDep
from service.broadcast import TIMEOUT, Stream, TooManyStreams

router = APIRouter()


async def event_stream(broadcast: BroadcastDep) -> Stream:
    """A slot in the app's Broadcast, or 429 when every slot is taken."""
    try:
        return broadcast.open()
    except TooManyStreams as exc:
        raise HTTPException(429, f"{exc}: try again later", {"Retry-After": "30"}) from None


@router.get(
    "/events",
    response_class=EventSourceResponse,
    responses={429: {"description": "too many open streams ([api] max_event_streams)"}},
)
async def get_events(
    request: Request,
    broadcast: BroadcastDep,
    stream: Annotated[Stream, Depends(event_stream)],
) -> AsyncIterator[ServerSentEvent]:
    """Server-Sent Events: ``event: coefficients`` with the published JSON as ``data``
    (the current version first, if any), a comment heartbeat when idle."""
    heartbeat_s: float = request.app.state.heartbeat_s
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
