"""What the Store hands out and takes in: plain records, no ORM session behind them."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np


def utc_now() -> datetime:
    return datetime.now(UTC)


@dataclass(kw_only=True)
class CalibrationRecord:
    """One calibration, accepted or not, as stored and served (construct with keywords).

    ``document`` is the ``recal calibrate --json`` object; ``version`` is None before insert.
    """

    version: int | None = None
    created_at: datetime = field(default_factory=utc_now)
    trigger: str
    method: str
    accepted: bool
    reasons: list[str] = field(default_factory=list)
    document: dict[str, Any]
    positions_used: list[int] = field(default_factory=list)
    prior_version: int | None = None


@dataclass(frozen=True)
class SlewRecord:
    """A stored slew (see :class:`service.store.rows.SlewRow`); ``groups`` is None when it was
    dropped."""

    first_id: int
    second_id: int
    period_s: float
    samples: int
    reference: np.ndarray | None
    groups: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None
    dropped: str | None
