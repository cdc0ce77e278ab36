"""``/positions``: the stored windows, one JSON object per row."""

from __future__ import annotations

import math
from typing import Annotated

from fastapi import APIRouter, Query

from service.api.models import MAX_DB_INT
from service.api.state import StoreDep

router = APIRouter()


@router.get("/positions")
def get_positions(
    store: StoreDep,
    limit: Annotated[int, Query(ge=1, le=100_000)] = 1000,
    since_id: Annotated[int | None, Query(ge=0, le=MAX_DB_INT)] = None,
) -> list[dict[str, float | int | None]]:
    """Stored positions in id order (the first ``limit`` after ``since_id``), one object
    per row: ``id`` and the columns common to the rows (NaN as null)."""
    table, ids = store.positions(since_id=since_id, limit=limit)
    names = list(table.columns)
    return [
        {"id": pid} | {n: _finite(table.columns[n][i]) for n in names} for i, pid in enumerate(ids)
    ]


def _finite(value: float) -> float | None:
    """JSON has no NaN or infinity: those become null."""
    return float(value) if math.isfinite(value) else None
