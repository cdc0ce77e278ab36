"""``/coefficients`` (the current version), ``/coefficients/history`` and
``/coefficients/{version}``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query

from service.api.models import MAX_DB_INT, CalibrationOut, CalibrationSummaryOut, DbId
from service.api.state import StoreDep
from service.store.records import CalibrationRecord
from service.store.repository import Store

#: Largest page of whole records from ``/coefficients/history?full=true``.
MAX_FULL_HISTORY = 100

router = APIRouter()


# No docstrings on get_current and get_version: FastAPI would publish them as descriptions.
@router.get("/coefficients", response_model=CalibrationOut, responses={404: {}})
def get_current(store: StoreDep) -> CalibrationOut:
    record = store.current()
    if record is None:
        raise HTTPException(404, "no accepted calibration yet")
    return CalibrationOut.of(record)


# Declared before /coefficients/{version}, which would otherwise take "history" as a version.
@router.get(
    "/coefficients/history",
    response_model=list[CalibrationSummaryOut] | list[CalibrationOut],
    responses={422: {"description": "bad paging parameters"}},
)
def get_history(
    store: StoreDep,
    limit: Annotated[int, Query(ge=1, le=1000)] = 50,
    before_version: Annotated[int | None, Query(ge=1, le=MAX_DB_INT)] = None,
    full: bool = False,
) -> list[CalibrationSummaryOut] | list[CalibrationOut]:
    """Calibrations, accepted or not, newest first: summaries (version, time, accepted,
    reasons, key figures), or whole records with ``full=true`` (then at most 100 a page,
    whatever ``limit`` says).
    The next page is ``before_version=<the last version listed>``."""
    if not full:
        return [CalibrationSummaryOut(**s) for s in store.history_summaries(limit, before_version)]
    records = full_history(store, min(limit, MAX_FULL_HISTORY), before_version)
    return [CalibrationOut.of(r) for r in records]


@router.get("/coefficients/{version}", response_model=CalibrationOut, responses={404: {}})
def get_version(store: StoreDep, version: DbId) -> CalibrationOut:
    record = store.calibration(version)
    if record is None:
        raise HTTPException(404, f"no calibration version {version}")
    return CalibrationOut.of(record)


def full_history(store: Store, limit: int, before_version: int | None) -> list[CalibrationRecord]:
    """Whole records for one history page (the summaries give the versions)."""
    if before_version is None:
        return store.history(limit)
    versions = [s["version"] for s in store.history_summaries(limit, before_version)]
    records = (store.calibration(v) for v in versions)
    return [r for r in records if r is not None]
