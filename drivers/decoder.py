"""Incremental decoder: feed it reads of any size, get the frames completed so far."""

from __future__ import annotations

import math
import time

import numpy as np

from .bulk import Chunks, Continuity, Engine
from .config import DEFAULT_CONFIG, DecoderConfig
from .formats import FrameFormat
from .frames import DecoderCounters, FrameBatch


class StreamDecoder:
    """Streaming decoder for one format.

    ``feed(data, host_time)`` returns the frames decided so far as a FrameBatch; each gets the
    host receive time of the feed that brought its last byte (time.monotonic() unless given;
    the reader passes the time its read returned). Bytes that may start a frame not yet
    complete, or a frame whose acceptance depends on the next bytes (a possible header inside
    it), are held back; they are always fewer than two frames, so the buffer is bounded.
    ``flush()`` ends the stream (e.g. on disconnect): held bytes are decided as at the end of a
    capture while sequence continuity is kept, so frames lost across a reconnect show as a
    sequence gap; with host times, a loss of 128 frames or more is counted in full.
    """

    def __init__(self, fmt: str | FrameFormat = "kvh-a", config: DecoderConfig = DEFAULT_CONFIG):
        self._engine = Engine(fmt, config)
        self._state = Continuity()
        self._pending = b""
        self._marks: list[tuple[int, float]] = []  # (end in _pending, host time) per read
        self.counters: DecoderCounters = self._engine.new_counters()

    @property
    def format(self) -> FrameFormat:
        return self._engine.fmt

    @property
    def config(self) -> DecoderConfig:
        return self._engine.config

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._pending)

    def feed(
        self, data: bytes | bytearray | memoryview, host_time: float | None = None
    ) -> FrameBatch:
        """Add received bytes; return the frames they complete (possibly none)."""
        if host_time is None:
            host_time = time.monotonic()
        data = bytes(data)
        if not data:
            return self._engine.empty()
        self.counters.bytes_in += len(data)
        buf = self._pending + data if self._pending else data
        marks = [*self._marks, (len(buf), float(host_time))]
        batch, end, _ = self._engine.scan(
            np.frombuffer(buf, dtype=np.uint8), False, self._state, self.counters, _chunks(marks)
        )
        self._pending = buf[end:]
        self._marks = [(e - end, t) for e, t in marks if e > end]
        self.counters.bytes_pending = len(self._pending)
        return batch

    def flush(self, host_time: float | None = None) -> FrameBatch:
        """End of stream: decide the held-back bytes. Frames among them keep the host time of
        the feed that brought their last byte (``host_time`` is accepted for compatibility)."""
        if not self._pending:
            return self._engine.empty()
        buf, marks = self._pending, self._marks
        self._pending, self._marks = b"", []
        batch, _, _ = self._engine.scan(
            np.frombuffer(buf, dtype=np.uint8), True, self._state, self.counters, _chunks(marks)
        )
        self.counters.bytes_pending = 0
        return batch

    def restart_sequence(self) -> None:
        # Note: host-time continuity goes too; the next frame is the first of a new stream.
        """Forget sequence/time continuity (the next frame starts a new stream at time 0)."""
        self._state = Continuity(in_skip=self._state.in_skip)

    def decode_all(self, data: bytes, host_time: float = math.nan) -> FrameBatch:
        """feed(data) then flush(), concatenated."""
        return FrameBatch.concat([self.feed(data, host_time), self.flush(host_time)])


def _chunks(marks: list[tuple[int, float]]) -> Chunks:
    if len(marks) == 1:
        return Chunks(np.array([marks[0][0]], np.int64), np.array([marks[0][1]], np.float64))
    ends, times = zip(*marks, strict=True)
    return Chunks(np.array(ends, np.int64), np.array(times, np.float64))
