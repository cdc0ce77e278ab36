"""Incremental decoder: feed it reads of any size, get the frames completed so far."""

from __future__ import annotations

import math
import time

import numpy as np

from .bulk import Continuity, Engine
from .config import DEFAULT_CONFIG, DecoderConfig
from .formats import FrameFormat
from .frames import DecoderCounters, FrameBatch


class StreamDecoder:
    """Streaming decoder for one format.

    ``feed(data)`` returns the frames completed by ``data`` as a FrameBatch; all of them get the
    host receive time of this call (time.monotonic() unless given). Bytes that may start a frame
    not yet complete are held back; they are always fewer than one frame, so the buffer is
    bounded. ``flush()`` ends the stream (e.g. on disconnect): held bytes count as skipped (and
    a cut-off frame as truncated) while sequence continuity is kept, so frames lost across a
    reconnect show as a sequence gap.
    """

    def __init__(self, fmt: str | FrameFormat = "kvh-a", config: DecoderConfig = DEFAULT_CONFIG):
        self._engine = Engine(fmt, config)
        self._state = Continuity()
        self._pending = b""
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
        batch, end, _ = self._engine.scan(
            np.frombuffer(buf, dtype=np.uint8), False, self._state, self.counters, host_time
        )
        self._pending = buf[end:]
        self.counters.bytes_pending = len(self._pending)
        return batch

    def flush(self, host_time: float | None = None) -> FrameBatch:
        """End of stream: decide the held-back bytes (they hold no complete frame)."""
        if not self._pending:
            return self._engine.empty()
        if host_time is None:
            host_time = time.monotonic()
        buf = self._pending
        self._pending = b""
        batch, _, _ = self._engine.scan(
            np.frombuffer(buf, dtype=np.uint8), True, self._state, self.counters, host_time
        )
        self.counters.bytes_pending = 0
        return batch

    def restart_sequence(self) -> None:
        """Forget sequence/time continuity (the next frame starts a new stream at time 0)."""
        self._state = Continuity(in_skip=self._state.in_skip)

    def decode_all(self, data: bytes, host_time: float = math.nan) -> FrameBatch:
        """feed(data) then flush(), concatenated."""
        return FrameBatch.concat([self.feed(data, host_time), self.flush(host_time)])
