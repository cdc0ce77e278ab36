"""Operational events: one log line each (journald shows them) and one row in the store.

Every event the operator may need (a window stored, a job started or failed, a version accepted
or rejected with its reasons, the device connected or lost, the published file written) goes
through :class:`Events`, so the log and ``GET /log`` tell the same story. The log line is
``event=<kind> <message> key=value ...``: one line, greppable, no traceback for expected
failures. When the database is down the event is still logged, and the failure is counted.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

log = logging.getLogger("recal.events")


def _fmt(value: Any) -> str:
    text = str(value)
    return f'"{text}"' if (" " in text or not text) else text


class Events:
    """Logs and stores events; never raises (an event must not break what it reports)."""

    def __init__(self, store: Any) -> None:
        self._store = store
        self.unstored = 0  # events that could only be logged (database unavailable)

    def emit(
        self,
        kind: str,
        message: str,
        data: Mapping[str, Any] | None = None,
        level: int = logging.INFO,
    ) -> None:
        fields = " ".join(f"{k}={_fmt(v)}" for k, v in (data or {}).items())
        log.log(level, "event=%s %s%s", kind, message, f" {fields}" if fields else "")
        try:
            self._store.add_event(kind, message, None if data is None else dict(data))
        except Exception:  # noqa: BLE001 - database down: the log line is what remains
            self.unstored += 1
