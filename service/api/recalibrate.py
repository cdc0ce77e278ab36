"""``POST /recalibrate``: queue a manual recalibration (needs the bearer token)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Request

from service.api.models import QueuedOut
from service.api.security import require_token

router = APIRouter()


@router.post(
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
def post_recalibrate(request: Request) -> QueuedOut:
    """Queue a recalibration on the stored positions (needs the bearer token)."""
    state = request.app.state
    if state.trigger is None:
        raise HTTPException(503, "manual recalibration is not available in this service")
    with state.trigger_lock:  # concurrent requests: one queues a job, the others hear why not
        try:
            job = state.trigger()
        except RuntimeError as exc:  # busy, or the scheduler is shutting down
            raise HTTPException(409, str(exc) or "a recalibration cannot start now") from None
    if job is None:
        raise HTTPException(409, "a recalibration is already running")
    return QueuedOut(queued=True, job=job)
