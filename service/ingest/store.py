"""Where the ingest's windows go (:class:`WindowStore`): each detector call's windows made
durable in the spool before they count as detected, then stored in the database in order, with
back-off while it is down, and the events that say so."""

from __future__ import annotations

import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from recal.errors import RecalInputError
from service.events import Events
from service.spool import Spool, SpoolEntry, SpoolWriteError, read_entry
from service.store.errors import StoreError, UnknownSessionError

log = logging.getLogger("recal.pipeline")

#: Windows kept in memory while both the database and the spool folder refuse them (a week of
#: windows at one a minute); windows on disk are not limited.
SPOOL_MAX = 10_000
#: Back-off between attempts to store spooled windows, s.
SPOOL_RETRY_MIN_S, SPOOL_RETRY_MAX_S = 0.5, 30.0


@dataclass(eq=False)
class _Spooled:
    """A batch of windows (one detector call) waiting for the database, in order: on disk
    (``entry`` None: read back from ``path`` when stored) or, when the spool could not take
    it, held in memory (``entry``)."""

    key: str
    windows: int
    path: Path | None = None
    entry: SpoolEntry | None = None
    replayed: bool = False  # spooled by an earlier run: it may already be stored

    def load(self) -> SpoolEntry:
        return self.entry if self.entry is not None else read_entry(self.path)


class WindowStore:
    """Stores the windows of one session (``session_id``) in ``store``, through the ``spool``
    (:class:`service.spool.Spool`; None: straight to the database).

    Each batch (one detector call's windows, with the slews between them) is written to the
    spool durably *before* it counts as detected (``detected``) and goes to the database; its
    file is deleted once the database committed it. Batches a previous run left in the spool
    are queued first, in order (:meth:`replay`). During a database outage batches wait on disk,
    retried with exponential back-off (:meth:`drain_if_due`). When the spool folder refuses a
    write (disk full, permissions) the error is kept in ``spool_error`` and the batch goes
    straight to the database; only when both refuse is it held in memory, bounded
    (:data:`SPOOL_MAX` windows, overflow counted in ``windows_dropped``). ``on_positions``
    hears the ids of the positions stored."""

    def __init__(
        self,
        store: Any,
        session_id: int,
        events: Events,
        spool: Spool | None = None,
        on_positions: Callable[[list[int]], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._store = store
        self._session = session_id
        self._events = events
        self._disk = spool
        self._on_positions = on_positions
        self._clock = clock
        self._spool: deque[_Spooled] = deque()
        self.spool_error: str | None = None  # why the spool folder refused the last batch
        self.windows_in_memory = 0  # windows neither on disk nor stored (both refused them)
        self.detected = 0  # windows made durable (spool or database): they survive a kill
        self.replayed = 0  # windows of earlier runs stored from the spool by this one
        self._last_key: str | None = None  # this session's last batch (row -1 of the next)
        self._stored_last: tuple[str, int] | None = None  # the last batch stored: key, last id
        self.slews = 0
        self.slews_dropped: dict[str, int] = {}
        self._retry_at = 0.0
        self._backoff_s = SPOOL_RETRY_MIN_S
        self.store_error: str | None = None
        self.windows = 0
        self.windows_dropped = 0

    def put(self, columns: dict[str, Any], slews: list[Any], period_s: float | None) -> None:
        """Queue one detector call's windows (their table ``columns``, the ``slews`` between
        them as (row a, row b, reduced slew), the sample period): on disk first, else in
        memory; the database is tried at the next :meth:`drain_if_due`."""
        entry = SpoolEntry(self._session, columns, slews, self._last_key, period_s)
        self._last_key = entry.key
        self._hold(entry)
        self._retry_at = 0.0  # new data: try the database now

    def drain_if_due(self) -> list[int]:
        """Store what waits, unless the back-off after a database failure has not passed;
        returns the ids stored."""
        return self._drain() if self._spool and self._clock() >= self._retry_at else []

    @property
    def spooled(self) -> int:
        """Windows waiting for the database (on disk or in memory)."""
        return sum(item.windows for item in self._spool)

    def spool_health(self) -> dict[str, Any]:
        """The spool as ``/health`` shows it."""
        on_disk = [item for item in self._spool if item.path is not None]
        return {
            "dir": None if self._disk is None else str(self._disk.directory),
            "batches_on_disk": len(on_disk),
            "windows_on_disk": sum(item.windows for item in on_disk),
            "windows_in_memory": self.windows_in_memory,
            "windows_replayed": self.replayed,
            "error": self.spool_error,
        }

    def replay(self) -> list[int]:
        """Queue the batches earlier runs left in the spool (oldest first, ahead of any new
        window) and store what the database takes now; returns the ids stored (the caller
        holds the ingest's lock)."""
        if self._disk is None:
            return []
        try:
            self._disk.probe()
        except SpoolWriteError as exc:
            self._spool_failed(exc)
        entries = self._disk.load()
        for bad in self._disk.unreadable:
            self._events.emit("spool", f"unreadable spool file kept as .bad: {bad}",
                              level=logging.ERROR)  # fmt: skip
        if entries:
            n = sum(e.size for e in entries)
            self._events.emit("spool", f"replaying {n} window(s) in {len(entries)} batch(es) "
                              f"from {self._disk.directory}", {"windows": n})  # fmt: skip
        old = [_Spooled(e.key, e.size, e.path, replayed=True) for e in entries]
        self._spool.extendleft(reversed(old))
        self._retry_at = 0.0
        return self._drain() if self._spool else []

    def _spool_failed(self, exc: SpoolWriteError) -> None:
        if self.spool_error != str(exc):
            self._events.emit("spool", f"{exc}: storing windows straight to the database, in "
                              "memory while it is down", {"dir": str(self._disk.directory)},
                              level=logging.ERROR)  # fmt: skip
        self.spool_error = str(exc)

    def _hold(self, entry: SpoolEntry) -> None:
        """Queue a new batch: on disk first (durable before it counts as detected); when the
        spool refuses it, in memory, where the drain that follows stores it if it can."""
        if self._disk is not None:
            try:
                self._disk.append(entry)
            except SpoolWriteError as exc:
                self._spool_failed(exc)
            else:
                if self.spool_error is not None:
                    self._events.emit("spool", f"spool {self._disk.directory} writable again")
                self.spool_error = None
                self._spool.append(_Spooled(entry.key, entry.size, entry.path))
                self.detected += entry.size
                return
        self._spool.append(_Spooled(entry.key, entry.size, entry=entry))
        self.windows_in_memory += entry.size
        while self.windows_in_memory > SPOOL_MAX:  # drop the oldest batch held in memory
            old = next(item for item in self._spool if item.entry is not None)
            self._spool.remove(old)
            self.windows_in_memory -= old.windows
            self.windows_dropped += old.windows

    def _drain(self) -> list[int]:
        """Store queued batches in order until none is left or the database fails."""
        stored: list[int] = []
        while self._spool:
            item = self._spool[0]
            try:
                entry = item.load()
            except (OSError, ValueError, KeyError) as exc:  # the file went bad under us
                self._events.emit("spool", f"cannot read spooled batch {item.path}: {exc}",
                                  level=logging.ERROR)  # fmt: skip
                self._spool.popleft()
                self.windows_dropped += item.windows
                continue
            try:
                ids = self._store_entry(entry, item.replayed)
            except (UnknownSessionError, RecalInputError) as exc:  # retrying cannot help
                self._set_aside(item, str(exc))
                continue
            except StoreError as exc:
                if self.store_error is None:
                    where = "spooling them" if self._disk is None else "they wait in the spool"
                    self._events.emit("database", f"cannot store windows, {where}: {exc}",
                                      level=logging.WARNING)  # fmt: skip
                self.store_error = str(exc)
                self._retry_at = self._clock() + self._backoff_s
                self._backoff_s = min(2 * self._backoff_s, SPOOL_RETRY_MAX_S)
                break
            self._spool.popleft()
            if item.entry is not None:  # durable only now
                self.windows_in_memory -= item.windows
                self.detected += item.windows
            if self._disk is not None and entry.path is not None:
                try:
                    self._disk.remove(entry)
                except OSError as exc:  # committed with its key: a replay of it adds nothing
                    log.warning("event=spool cannot delete %s: %s", entry.path, exc)
            if ids is None:  # an earlier run stored it and was killed before the delete
                continue
            stored += ids
            if item.replayed:
                self.replayed += len(ids)
        if stored:
            if self.store_error is not None:
                self._events.emit("database", "database back: spooled windows stored",
                                  {"windows": len(stored)})  # fmt: skip
            self.store_error = None
            self._backoff_s = SPOOL_RETRY_MIN_S
            self.windows += len(stored)
            log.info("event=window stored %d window(s), ids %s", len(stored), stored)
            if self._on_positions:
                self._on_positions(stored)
        return stored

    def _set_aside(self, item: _Spooled, why: str) -> None:
        """A batch the database can never take (e.g. a spool from another database): out of
        the queue, its file kept as ``*.bad`` for a person to look at."""
        self._spool.popleft()
        self.windows_dropped += item.windows
        if item.entry is not None:
            self.windows_in_memory -= item.windows
        if item.path is not None:
            with contextlib.suppress(OSError):
                item.path.rename(item.path.with_suffix(".bad"))
        self._events.emit("spool", f"batch {item.key} ({item.windows} window(s)) cannot be "
                          f"stored, set aside: {why}", level=logging.ERROR)  # fmt: skip

    def _store_entry(self, entry: SpoolEntry, replayed: bool) -> list[int] | None:
        """Store one batch with its slews (StoreError if the database refuses); None when a
        replayed batch is stored already."""
        if replayed and self._store.keyed_positions(entry.key):
            return None
        previous = None  # the last window of the batch before, if it was stored
        if entry.previous_key is not None:
            if self._stored_last is not None and self._stored_last[0] == entry.previous_key:
                previous = self._stored_last[1]
            elif replayed:
                before = self._store.keyed_positions(entry.previous_key)
                previous = before[-1] if before else None
        ids = self._store.add_positions(entry.session_id, entry.columns, entry.slews,
                                        entry.period_s, previous, spool_key=entry.key)  # fmt: skip
        if ids:
            self._stored_last = (entry.key, ids[-1])
        for a, _, r in entry.slews:
            if a < 0 and previous is None:
                continue  # its first window was never stored: not stored
            if r.dropped is None:
                self.slews += 1
            else:
                self.slews_dropped[r.dropped] = self.slews_dropped.get(r.dropped, 0) + 1
        return ids
