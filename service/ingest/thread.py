"""The ingest in a thread of its own (:class:`IngestThread`), so the reader never waits."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from service.pipeline import Ingest

log = logging.getLogger("recal.pipeline")

#: Queued to the ingest thread by :meth:`IngestThread.end`: the input has ended.
_END = object()


class IngestThread:
    """Hands the reader's batches to :class:`Ingest` in a thread of its own ("ingest").

    The reader thread must never wait: the detector, the spool's fsync and the database take
    milliseconds to seconds, and a reader that stalls lets the serial buffer overflow and makes
    a format without timestamps date its frames from their late arrival. :meth:`put` only
    queues; the thread feeds Ingest in order. :meth:`stop` drains the queue first. :meth:`end`
    (the reader's end of input) is queued too, so Ingest hears of it after the last frame.
    """

    def __init__(self, ingest: Ingest) -> None:
        import queue

        self._ingest = ingest
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._oldest: float | None = None  # host time of the oldest batch not yet fed
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._queued = 0  # batches put and not yet fed
        self._thread = threading.Thread(target=self._loop, name="ingest", daemon=True)
        self._thread.start()

    def put(self, batch: Any) -> None:
        """Queue a drivers.FrameBatch (the reader's callback; returns at once)."""
        with self._lock:
            if self._oldest is None:
                self._oldest = time.monotonic()
            self._queued += 1
        self._queue.put(batch)

    def end(self) -> None:
        """The input has ended: :meth:`Ingest.end_of_input` once every batch queued before
        has been fed (returns at once, as :meth:`put`)."""
        self.put(_END)

    def _loop(self) -> None:
        while True:
            batch = self._queue.get()
            if batch is None:
                return
            try:
                if batch is _END:
                    self._ingest.end_of_input()
                else:
                    self._ingest.feed(batch)
            except Exception:  # noqa: BLE001 - one bad batch must not end the ingest
                log.exception("ingest: a batch failed")
            with self._lock:
                self._queued -= 1
                self._oldest = None if self._queued == 0 else time.monotonic()
                if self._queued == 0:
                    self._idle.notify_all()

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until every batch put so far has been fed; False on timeout."""
        with self._idle:
            return self._idle.wait_for(lambda: self._queued == 0, timeout_s)

    def waiting_s(self) -> float | None:
        """How long the oldest queued batch has waited (host s), None when none waits."""
        with self._lock:
            return None if self._oldest is None else time.monotonic() - self._oldest

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 60.0) -> None:
        """Feed what is queued, then end the thread."""
        self._queue.put(None)
        self._thread.join(timeout_s)
