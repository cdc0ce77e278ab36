"""Publication of accepted coefficients: an atomic JSON file plus in-process subscribers.

The navigation computer reads the file (always complete: written to a temporary file in the same
folder, fsynced, then renamed over the old one) or listens on the SSE endpoint, which drains a
:class:`Subscription` queue. A slow subscriber never blocks :meth:`Publisher.publish`: its queue
is bounded and loses its oldest item when full, and the loss is counted.

The file follows the database: :meth:`Publisher.sync` (called at start, after every acceptance
and periodically by the daemon) rewrites it whenever it differs from the current accepted
version: a crash between the commit and the write, a deleted or edited file, or a write that
failed (read-only mount, full disk) and is retried. A failure is kept in ``error`` for
``/health``; it never raises into the pipeline.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import tempfile
import threading
from collections.abc import Mapping
from contextlib import suppress
from pathlib import Path
from typing import Any

from recal.model.published import published_metadata
from service.store.records import CalibrationRecord

log = logging.getLogger("recal.publish")


def payload(record: CalibrationRecord) -> dict[str, Any]:
    """The published object: version, creation time, the coefficient sections and what was held
    at the prior (``held``: flat name -> the prior's value and 1-sigma; null in versions stored
    before jobs recorded it, whose ``status`` still says which were held). Beside them what
    makes the file self-describing (recal.model.published, docs/apply.md): ``schema``,
    ``model`` (equations, units, T0) and ``calibration_temperature_c``."""
    if record.version is None:
        raise ValueError("only a stored calibration (with a version) can be published")
    doc = record.document
    return {
        "version": record.version,
        "created_at": record.created_at.isoformat(),
        "coefficients": doc.get("coefficients"),
        "status": doc.get("status"),
        "uncertainty": doc.get("uncertainty"),
        "held": doc.get("held"),
        **published_metadata(doc.get("coefficients")),
    }


def write_json_atomic(path: Path, obj: Any) -> None:
    """Replace ``path`` with ``obj`` as JSON so readers see the old or the new file, never a mix."""
    data = (json.dumps(obj, indent=2, allow_nan=False) + "\n").encode()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o644)  # mkstemp's 0600 would hide it from other readers
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)  # make the rename itself survive a power cut


def check_publish_path(path: Path) -> None:
    """Raise a one-line :class:`RecalInputError` unless ``path`` can be written: its folder is
    created if missing, must be a writable directory, and ``path`` must not be a directory."""
    from recal.errors import RecalInputError

    folder = path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecalInputError(
            f"publish_path {path}: cannot create its folder {folder}: {exc.strerror or exc}"
        ) from None
    if path.is_dir():
        raise RecalInputError(f"publish_path {path} is a directory; give a file name")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise RecalInputError(f"publish_path {path}: the folder {folder} is not writable")


def _fsync_dir(folder: Path) -> None:
    with suppress(OSError):  # not every platform/filesystem lets a directory be fsynced
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class Subscription(queue.Queue):
    """A subscriber's bounded queue of published objects; ``None`` means the publisher closed.

    ``dropped`` counts objects discarded because the subscriber fell behind.
    """

    def __init__(self, maxsize: int) -> None:
        super().__init__(maxsize)
        self.dropped = 0

    def offer(self, item: dict[str, Any] | None) -> bool:
        """Enqueue without ever blocking, discarding the oldest item when full.

        Returns True when an item was discarded.
        """
        with self.mutex:  # the queue's own lock: drop-and-put is one step for consumers
            full = 0 < self.maxsize <= self._qsize()
            if full:
                self._get()
                self.dropped += 1
            else:
                self.unfinished_tasks += 1
            self._put(item)
            self.not_empty.notify()
        return full


class Publisher:
    """Atomic JSON file of the current coefficients plus a broadcast to subscribers.

    Thread-safe: publications are serialised, so every subscriber sees them in order.
    """

    def __init__(self, path: str | os.PathLike[str], queue_size: int = 64) -> None:
        self.path = Path(path)
        check_publish_path(self.path)
        self.queue_size = queue_size
        self._lock = threading.Lock()
        self._subscribers: list[Subscription] = []
        self._latest: dict[str, Any] | None = None
        self._closed = False
        self._dropped = 0
        self.error: str | None = None  # the last failed write, until one succeeds
        self.writes = 0

    def sync(self, record: CalibrationRecord | None) -> bool:
        """Make the file (and the subscribers' latest) equal ``record``, the current accepted
        version. Returns True when the file was (re)written; a failure is kept in ``error``."""
        if record is None:
            return False
        obj = payload(record)
        try:
            on_disk = json.loads(self.path.read_text())
        except (OSError, ValueError):
            on_disk = None
        if on_disk == obj and self.error is None:
            with self._lock:
                self._latest = obj
            return False
        try:
            self.publish(record)
        except OSError as exc:
            first = self.error is None
            self.error = f"cannot write {self.path}: {exc.strerror or exc}"
            if first:
                log.error("event=publish %s (version %s)", self.error, record.version)
            return False
        if self.error is not None:
            log.info("event=publish %s written again after: %s", self.path, self.error)
        self.error = None
        return True

    def publish(self, record: CalibrationRecord) -> dict[str, Any]:
        """Write the file, then hand the same object to every subscriber; returns it."""
        obj = payload(record)
        with self._lock:
            write_json_atomic(self.path, obj)
            self.writes += 1
            new = self._latest is None or self._latest.get("version") != obj["version"]
            self._latest = obj
            if new:  # a rewrite of the same version is not news to subscribers
                self._dropped += sum(sub.offer(obj) for sub in self._subscribers)
        log.info("event=publish version %s written to %s", obj["version"], self.path)
        return obj

    def subscribe(self, maxsize: int | None = None, current: bool = True) -> Subscription:
        """A new queue receiving the current version first (``current``), then every later
        publication (just ``None`` once closed)."""
        sub = Subscription(maxsize or self.queue_size)
        with self._lock:
            if self._closed:
                sub.offer(None)
            else:
                if current and self._latest is not None:
                    sub.offer(self._latest)
                self._subscribers.append(sub)
        return sub

    def unsubscribe(self, sub: queue.Queue) -> None:
        with self._lock, suppress(ValueError):
            self._subscribers.remove(sub)  # type: ignore[arg-type]

    def close(self) -> None:
        """End every subscription (SSE streams finish); later publications still write the file."""
        with self._lock:
            self._closed = True
            for sub in self._subscribers:
                sub.offer(None)
            self._subscribers.clear()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def latest(self) -> Mapping[str, Any] | None:
        """The last object published by this process."""
        return self._latest

    @property
    def subscriber_count(self) -> int:
        with self._lock:
            return len(self._subscribers)

    @property
    def dropped(self) -> int:
        """Objects dropped so far because a subscriber fell behind (all subscribers)."""
        return self._dropped
