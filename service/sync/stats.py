"""What ``/health`` shows of the link (``sync`` block): its state, the last error, the last
contact and the traffic per UTC day. The traffic and the last contact are kept in the database
(table ``sync_days``: bytes sent compressed, every attempt counted; rows acknowledged), so they
survive restarts; the state and the error live in memory."""

from __future__ import annotations

import threading
from datetime import UTC, datetime, timedelta
from typing import Any

from service.sync.batch import iso_utc

#: Days of traffic ``/health`` lists (today included).
DAYS_SHOWN = 7

OFF, UP, DOWN, REJECTED = "off", "up", "down", "rejected"


class SyncStats:
    """Thread-safe: the sync thread writes, the API's threads read :meth:`snapshot`."""

    def __init__(self, url: str, unit: str) -> None:
        self.url = url
        self.unit = unit
        self._lock = threading.Lock()
        self.state = DOWN  # until the shore first answers
        self.last_error: str | None = None
        self.last_contact: datetime | None = None
        self._days: dict[str, dict[str, int]] = {}  # day -> bytes, rows (the last few days)
        self.loaded = False

    def load(self, store: Any) -> None:
        """Read the persisted traffic and last contact (StoreError if the database is down)."""
        since = (datetime.now(UTC).date() - timedelta(days=DAYS_SHOWN - 1)).isoformat()
        days = store.sync_traffic(since)
        contact = store.sync_last_contact()
        with self._lock:  # the database has every count made so far that it could take
            for d in days:
                self._days[d["day"]] = {"bytes": int(d["bytes"]), "rows": int(d["rows"])}
            if contact is not None and (self.last_contact is None or contact > self.last_contact):
                self.last_contact = contact
            self.loaded = True

    def count(self, day: str, sent_bytes: int, rows: int = 0) -> None:
        """Traffic the store has just been told of (kept here for :meth:`snapshot`)."""
        with self._lock:
            mine = self._days.setdefault(day, {"bytes": 0, "rows": 0})
            mine["bytes"] += int(sent_bytes)
            mine["rows"] += int(rows)
            keep = sorted(self._days)[-DAYS_SHOWN:]
            self._days = {d: self._days[d] for d in keep}

    def up(self, at: datetime) -> None:
        with self._lock:
            self.state, self.last_error, self.last_contact = UP, None, at

    def down(self, error: str, rejected: bool = False, contact: datetime | None = None) -> None:
        """The link failed (``rejected``: the shore answered and refused; ``contact``: when)."""
        with self._lock:
            self.state = REJECTED if rejected else DOWN
            self.last_error = error
            if contact is not None:
                self.last_contact = contact

    def note(self, error: str) -> None:
        """An error that says nothing of the link (the database's): shown, state kept."""
        with self._lock:
            self.last_error = error

    def snapshot(self, backlog: int | None) -> dict[str, Any]:
        """The ``sync`` block of ``/health``."""
        today = datetime.now(UTC).date()
        with self._lock:
            days = [(today - timedelta(days=n)).isoformat() for n in range(DAYS_SHOWN - 1, -1, -1)]
            per_day = [{"day": d, **self._days.get(d, {"bytes": 0, "rows": 0})} for d in days]
            return {
                "state": self.state,
                "url": self.url,
                "unit": self.unit,
                "backlog": backlog,
                "last_contact": None if self.last_contact is None else iso_utc(self.last_contact),
                "last_error": self.last_error,
                "bytes_today": per_day[-1]["bytes"],
                "bytes_per_day": per_day,
            }


def off_block(backlog: int | None) -> dict[str, Any]:
    """The ``sync`` block without a ``[sync]`` section."""
    return {"state": OFF, "url": None, "unit": None, "backlog": backlog, "last_contact": None,
            "last_error": None, "bytes_today": 0, "bytes_per_day": []}  # fmt: skip


__all__ = ["DAYS_SHOWN", "DOWN", "OFF", "REJECTED", "UP", "SyncStats", "off_block"]
