"""Bytes to whole lines: the cut a line format's parser is fed at (a serial read or a file
chunk ends anywhere, a parser wants whole lines)."""

from __future__ import annotations

#: Longest partial line carried between reads; a stream without newlines is not a line format.
MAX_LINE_BYTES = 1 << 20


class LineSplitter:
    """``feed(bytes)`` returns the whole lines they complete, as one block ending in ``\\n``
    (empty when none is complete); the partial line after the last ``\\n`` waits for the next
    read. ``flush()`` returns what is left (a last line without a newline) and clears it;
    ``drop()`` forgets it (a reconnect: the line was cut)."""

    def __init__(self, max_line: int = MAX_LINE_BYTES) -> None:
        self._carry = b""
        self.max_line = max_line
        self.dropped_bytes = 0  # bytes of over-long or cut lines thrown away

    @property
    def pending(self) -> int:
        return len(self._carry)

    def feed(self, data: bytes | bytearray | memoryview) -> bytes:
        buf = self._carry + bytes(data) if self._carry else bytes(data)
        cut = buf.rfind(b"\n") + 1
        self._carry = buf[cut:]
        if len(self._carry) > self.max_line:  # no newline in sight: not lines, do not grow
            self.dropped_bytes += len(self._carry)
            self._carry = b""
        return buf[:cut]

    def flush(self) -> bytes:
        buf, self._carry = self._carry, b""
        return buf

    def drop(self) -> None:
        self.dropped_bytes += len(self._carry)
        self._carry = b""
