"""One Publisher subscription shared by every ``/events`` stream, with a cap on streams.

A single thread blocks on the Publisher's queue and hands each published object to every open
stream's asyncio queue (``call_soon_threadsafe``), so an idle stream costs nothing until
something is published or its heartbeat is due: no stream polls. ``None`` from the Publisher
(it closed: the service is stopping) ends every stream, and streams opened later end at once.
"""

from __future__ import annotations

import asyncio
import threading
import weakref
from typing import Any

#: What :meth:`Stream.next` returns when nothing arrived within its timeout.
TIMEOUT = object()


class TooManyStreams(RuntimeError):
    """Every stream slot is taken."""


class Stream:
    """One client's bounded queue of published objects (``None`` ends it); the oldest item is
    dropped, and counted, when the client falls behind."""

    def __init__(self, loop: asyncio.AbstractEventLoop, size: int) -> None:
        self._loop = loop
        self._queue: asyncio.Queue[Any] = asyncio.Queue(size)
        self.dropped = 0

    def push(self, item: dict[str, Any] | None) -> None:
        """Hand ``item`` to the stream from any thread."""
        try:
            self._loop.call_soon_threadsafe(self._put, item)
        except RuntimeError:  # the client's event loop is gone
            pass

    def _put(self, item: dict[str, Any] | None) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        self._queue.put_nowait(item)

    async def next(self, timeout: float) -> Any:
        """The next item, or :data:`TIMEOUT` after ``timeout`` seconds without one."""
        try:
            return await asyncio.wait_for(self._queue.get(), timeout)
        except TimeoutError:
            return TIMEOUT


class Broadcast:
    """Fan-out of ``publisher``'s publications to at most ``max_streams`` streams."""

    def __init__(self, publisher: Any, max_streams: int, queue_size: int = 16) -> None:
        self._publisher = publisher
        self.max_streams = max_streams
        self._queue_size = queue_size
        self._lock = threading.Lock()
        # weak: a stream whose response never started (client gone at once) frees its slot too
        self._streams: weakref.WeakSet[Stream] = weakref.WeakSet()
        self._pump: threading.Thread | None = None
        self._ended = False

    @property
    def count(self) -> int:
        """Open streams."""
        with self._lock:
            return len(self._streams)

    def open(self) -> Stream:
        """A new stream (call from its event loop); the latest publication comes first.

        Raises :class:`TooManyStreams` when ``max_streams`` are open.
        """
        stream = Stream(asyncio.get_running_loop(), self._queue_size)
        with self._lock:
            if self._ended:
                stream._put(None)
                return stream
            if len(self._streams) >= self.max_streams:
                raise TooManyStreams(f"{self.max_streams} event streams are open already")
            self._streams.add(stream)
            self._start()
        latest = self._publisher.latest
        if latest is not None:
            stream._put(dict(latest))
        return stream

    def close(self, stream: Stream) -> None:
        with self._lock:
            self._streams.discard(stream)

    def _start(self) -> None:
        if self._pump is None:  # the first stream subscribes (the lock is held)
            subscription = self._publisher.subscribe(current=False)  # open() sends the latest
            self._pump = threading.Thread(
                target=self._run, args=(subscription,), name="sse-broadcast", daemon=True
            )
            self._pump.start()

    def _run(self, subscription: Any) -> None:
        while True:
            item = subscription.get()
            with self._lock:
                streams = list(self._streams)
                if item is None:
                    self._ended = True
                    self._streams.clear()
            for stream in streams:
                stream.push(item)
            if item is None:
                return
