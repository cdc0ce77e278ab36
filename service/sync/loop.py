"""The sync thread: offers the outbox to the shore, batch after batch, and backs off when the
link fails (docs/fleet.md).

One step: build the next batch from the oldest outbox rows, POST it, and on 200 delete exactly
the outbox rows it settles, in one transaction with the day's traffic. A full batch is followed
at once by the next; otherwise the thread sleeps ``interval_s``. A failure without an answer
(no route, timeout, cut connection) or a 5xx / 429 backs off exponentially with jitter, up to
``backoff_cap_s``; an answer that retrying cannot mend (401, 403, 422, 413 for one row) makes
the state ``rejected`` with a clear error and is tried again only every ``rejected_retry_s``.
A 413 halves the batch and retries at once. The thread has its own database calls and its own
connection; :meth:`SyncThread.stop` aborts a request in flight, so stopping never waits for a
dead link.
"""

from __future__ import annotations

import contextlib
import logging
import os
import random
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from service.store.codec import utc_day
from service.store.errors import StoreError
from service.sync.batch import MAX_JSON_BYTES, MAX_ROWS, Batch, build
from service.sync.client import Link, LinkError, Reply
from service.sync.stats import DOWN, REJECTED, UP, SyncStats

log = logging.getLogger("recal.sync")

#: How often the fleet prior is fetched again while the link is up, s (its version changes
#: when the shore holds new accepted versions of the model: weeks, not hours).
PRIOR_EVERY_S = 6 * 3600.0
#: After a failed fetch, s.
PRIOR_RETRY_S = 600.0


class SyncThread:
    """The daemon's sync client: :meth:`start`, :meth:`stop`, :meth:`health`."""

    def __init__(
        self,
        store: Any,
        url: str,
        unit: str,
        token: str,
        interval_s: float = 60.0,
        *,
        events: Any = None,
        max_rows: int = MAX_ROWS,
        max_json_bytes: int = MAX_JSON_BYTES,
        connect_timeout_s: float = 10.0,
        read_timeout_s: float = 30.0,
        backoff_base_s: float = 1.0,
        backoff_cap_s: float = 300.0,
        rejected_retry_s: float = 900.0,
        prior_path: str | os.PathLike[str] | None = None,
        prior_every_s: float = PRIOR_EVERY_S,
    ) -> None:
        self.store = store
        self.unit = unit
        self.interval_s = interval_s
        self.events = events
        self.max_rows = max_rows
        self.max_json_bytes = max_json_bytes
        self.backoff_base_s = backoff_base_s
        self.backoff_cap_s = backoff_cap_s
        self.rejected_retry_s = rejected_retry_s
        #: where the fleet prior fetched from shore is kept (None: not fetched)
        self.prior_path = None if prior_path is None else Path(prior_path)
        self.prior_every_s = prior_every_s
        self._prior_due = 0.0  # time.monotonic() of the next fetch: at once after start
        self.link = Link(url, token, connect_timeout_s=connect_timeout_s,
                         read_timeout_s=read_timeout_s)  # fmt: skip
        self.stats = SyncStats(url, unit)
        self.failures = 0  # in a row, for the back-off
        self.batches = 0  # acknowledged since start
        self._announced: str | None = None  # the state the last sync event told
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None

    @classmethod
    def from_settings(cls, store: Any, sync: Any, events: Any = None, **kw: Any) -> SyncThread:
        """From a configured ``[sync]`` section (service.config.SyncSettings)."""
        return cls(store, sync.url, sync.unit, sync.token.get_secret_value(), sync.interval_s,
                   events=events, **kw)  # fmt: skip

    # ---- lifecycle ----------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self.run, name="sync", daemon=True)
            self._thread.start()

    @property
    def started(self) -> bool:
        return self._thread is not None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def stop(self, wait_s: float = 5.0) -> bool:
        """End the thread: a request in flight is aborted, a sleep cut short. Returns whether
        it ended within ``wait_s``."""
        self._stop.set()
        self._wake.set()
        self.link.abort()
        if self._thread is None:
            return True
        self._thread.join(wait_s)
        return not self._thread.is_alive()

    def poke(self) -> None:
        """Offer the outbox now instead of after the current sleep (e.g. new rows)."""
        self._wake.set()

    # ---- the loop -----------------------------------------------------------------------
    def run(self) -> None:
        delay = 0.0
        while not self._sleep(delay):
            try:
                delay = self.step()
            except Exception as exc:  # noqa: BLE001 - one bad step must not end the thread
                log.exception("sync step failed")
                self.stats.down(f"internal error: {exc}")
                delay = self._backoff()

    def _sleep(self, delay: float) -> bool:
        """Wait ``delay`` s (or until poked); True when stopping."""
        if delay > 0:
            self._wake.wait(delay)
            self._wake.clear()
        return self._stop.is_set()

    def step(self) -> float:
        """Offer one batch; returns how long to wait before the next step, s."""
        if not self.stats.loaded:
            try:
                self.stats.load(self.store)
            except StoreError as exc:
                log.warning("sync: cannot read the link's traffic yet: %s", exc)
        try:
            batch = build(self.store, self.unit, max_rows=self.max_rows,
                          max_json_bytes=self.max_json_bytes)  # fmt: skip
        except StoreError as exc:  # the database, not the link: try again later
            self.stats.note(f"database: {exc}")
            return self._backoff()
        if batch is None:
            self._fetch_prior()
            return self.interval_s
        if not batch.rows:  # only rows no longer stored: nothing to send
            try:
                self.store.sync_acknowledge(batch.settles)
            except StoreError as exc:
                self.stats.note(f"database: {exc}")
                return self._backoff()
            return 0.0
        sent_at = datetime.now(UTC)
        try:
            reply = self.link.post(batch.body)
        except LinkError as exc:
            self._count(sent_at, len(batch.body))
            if self._stop.is_set():
                return 0.0
            return self._failed(f"{exc}", batch)
        return self._answered(reply, batch, sent_at)

    def _answered(self, reply: Reply, batch: Batch, sent_at: datetime) -> float:
        now = datetime.now(UTC)
        if reply.status == 200:
            try:
                self.store.sync_acknowledge(batch.settles, day=utc_day(sent_at),
                                            sent_bytes=len(batch.body), rows=len(batch.rows),
                                            contact=now)  # fmt: skip
            except StoreError as exc:  # sent again later: the shore stores nothing twice
                self.stats.count(utc_day(sent_at), len(batch.body))
                self.stats.note(f"database: the acknowledged batch stays in the outbox: {exc}")
                return self._backoff()
            self.stats.count(utc_day(sent_at), len(batch.body), len(batch.rows))
            self.stats.up(now)
            self.failures = 0
            self.batches += 1
            told = self._announce(UP, f"link to {self.link.endpoint} up: {batch.describe()} "
                                  "delivered")  # fmt: skip
            # a backlog drains without pauses, and so does the event just stored
            return 0.0 if batch.more or told else self.interval_s
        self._count(sent_at, len(batch.body))
        detail = reply.detail()
        if reply.status == 413 and len(batch.rows) > 1:
            self.max_rows = max(1, len(batch.rows) // 2)
            self.max_json_bytes = max(1024, batch.json_bytes // 2)
            log.warning("sync: the shore refused %s as too large (413): sending at most %d rows "
                        "(%d bytes of JSON) a batch from now on", batch.describe(),
                        self.max_rows, self.max_json_bytes)  # fmt: skip
            return 0.0
        if reply.status in (401, 403, 413, 422):
            why = {
                401: f"the shore does not accept this unit's token (401: {detail}): check "
                "[sync] token (recal fleet add-unit prints it)",
                403: f"the shore's token is not for unit {self.unit} (403: {detail}): check "
                "[sync] unit and token",
                413: f"the shore refuses {batch.name_row(0)} as too large (413: {detail})",
                422: f"the shore refused the batch as malformed (422: {detail}); batch of "
                f"{batch.describe()}",
            }[reply.status]
            self.stats.down(why, rejected=True, contact=now)
            self._announce(REJECTED, why, logging.ERROR)
            self.failures += 1
            return self.rejected_retry_s
        return self._failed(f"the shore answered {reply.status}: {detail}", batch, contact=now)

    def _fetch_prior(self) -> None:
        """The fleet prior of this unit's model, from ``GET /fleet/prior`` when due (the outbox
        is empty and the link answers): saved to ``prior_path`` when its version or model is new,
        with a ``fleet_prior`` event. A shore without one yet (404), or a link that fails, leaves
        the file as it was until the next try (``prior_every_s``, 10 min after a failure)."""
        if self.prior_path is None or time.monotonic() < self._prior_due:
            return
        self._prior_due = time.monotonic() + min(self.prior_every_s, PRIOR_RETRY_S)
        try:
            reply = self.link.get("/fleet/prior")
        except LinkError as exc:
            log.info("sync: fleet prior not fetched: %s", exc)
            return
        if reply.status == 404:
            self._prior_due = time.monotonic() + self.prior_every_s
            log.info("sync: the shore has no fleet prior for this unit yet: %s", reply.detail())
            return
        if reply.status != 200 or not isinstance(reply.body, dict):
            log.warning("sync: fleet prior not fetched: the shore answered %d: %s",
                        reply.status, reply.detail())  # fmt: skip
            return
        from recal.errors import RecalInputError
        from recal.fleet.prior import read_fleet_prior
        from service.startup import read_fleet_prior_file, write_fleet_prior_file

        try:
            prior = read_fleet_prior(reply.body, source=f"{self.link.url}/fleet/prior")
        except RecalInputError as exc:
            log.warning("sync: the shore's fleet prior is refused: %s", exc)
            return
        self._prior_due = time.monotonic() + self.prior_every_s
        try:
            held = read_fleet_prior_file(str(self.prior_path))
        except RecalInputError:
            held = None  # none yet, or unreadable: replaced
        if held is not None and (held.model, held.version) == (prior.model, prior.version):
            return
        try:
            write_fleet_prior_file(str(self.prior_path), prior)
        except OSError as exc:
            log.warning("sync: cannot save the fleet prior to %s: %s", self.prior_path, exc)
            return
        message = (f"fleet prior v{prior.version} of model {prior.model} received from shore: "
                   f"the gate allows its ageing from the next recalibration")  # fmt: skip
        if self.events is not None:
            self.events.emit("fleet_prior", message, {"model": prior.model,
                             "version": prior.version, "path": str(self.prior_path)})  # fmt: skip
        else:
            log.info("sync: %s", message)

    def _failed(self, why: str, batch: Batch, contact: datetime | None = None) -> float:
        self.stats.down(why, contact=contact)
        self._announce(DOWN, f"link to {self.link.endpoint} down: {why} ({batch.describe()} "
                       "kept in the outbox)", logging.WARNING)  # fmt: skip
        return self._backoff()

    def _backoff(self) -> float:
        """Exponential back-off with jitter: between half and all of base x 2^failures, capped."""
        self.failures += 1
        ceiling = min(self.backoff_cap_s, self.backoff_base_s * 2 ** min(self.failures - 1, 30))
        return ceiling * random.uniform(0.5, 1.0)

    def _count(self, sent_at: datetime, sent_bytes: int) -> None:
        """Count bytes that went out without an acknowledgement (they used the link too)."""
        day = utc_day(sent_at)
        with contextlib.suppress(StoreError):  # the count in memory stays right until a restart
            self.store.sync_traffic_add(day, sent_bytes)
        self.stats.count(day, sent_bytes)

    def _announce(self, state: str, message: str, level: int = logging.INFO) -> bool:
        """A ``sync`` event when the state changes (not on every retry); returns whether one
        was told."""
        if state == self._announced:
            return False
        self._announced = state
        if self.events is not None:
            self.events.emit("sync", message, {"state": state}, level=level)
        else:
            log.log(level, "sync: %s", message)
        return True

    # ---- health -------------------------------------------------------------------------
    def health(self, backlog: int | None = None) -> dict[str, Any]:
        """The ``sync`` block of ``/health`` (``backlog``: outbox rows, when known)."""
        return self.stats.snapshot(backlog)


__all__ = ["SyncThread"]
