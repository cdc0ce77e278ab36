"""``udp://[HOST]:PORT``: a UDP listener served through pyserial's Serial interface.

On board, NMEA 0183 most often arrives as UDP broadcasts on port 10110 (shared/spec/vessel.md):
``udp://:10110`` listens on every interface, ``udp://127.0.0.1:10110`` on one address. Importing
:mod:`drivers.transport` lets ``serial.serial_for_url`` open it like any other port, so a reader
needs no second code path.

Each datagram is read whole and ends a line: a talker that sends one sentence per datagram
without its CR LF still gives whole lines. ``read(size)`` returns as soon as anything has come
(at most ``size`` bytes; what is left waits for the next read) or the timeout expires; the
socket is bound with ``SO_REUSEADDR`` (and ``SO_REUSEPORT`` where there is one), so other
listeners on the same broadcast port keep working.
"""

from __future__ import annotations

import select
import socket
import time
from urllib.parse import urlsplit

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, Timeout

#: Largest datagram read at once (an IP datagram's payload is at most this).
MAX_DATAGRAM = 65535
#: Longest a blocked read sleeps before it looks at cancel_read() again, s.
POLL_S = 0.05


def parse_udp_url(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> (host, port); host "" (every interface) when left out."""
    parts = urlsplit(url)
    if parts.scheme != "udp":
        raise ValueError(f"expected udp://[HOST]:PORT, not {url!r}")
    try:
        port = parts.port
    except ValueError as exc:
        raise ValueError(f"udp:// URL {url!r}: {exc}") from None
    if port is None or parts.path not in ("", "/") or parts.query:
        raise ValueError(f"expected udp://[HOST]:PORT, e.g. udp://:10110, not {url!r}")
    return parts.hostname or "", port


class Serial(SerialBase):
    """A bound UDP socket whose datagrams are read as a byte stream."""

    def __init__(self, *args, **kwargs) -> None:
        self._socket: socket.socket | None = None
        self._buffer = bytearray()
        self._cancel = False
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            host, port = parse_udp_url(self._port)
        except ValueError as exc:
            raise SerialException(str(exc)) from None
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.bind((host, port))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise SerialException(exc.errno, f"cannot listen on {self._port}: {exc}") from None
        self._socket = sock
        self._buffer.clear()
        self.is_open = True

    @property
    def local_port(self) -> int:
        """The port bound (useful after ``udp://127.0.0.1:0``)."""
        if self._socket is None:
            raise PortNotOpenError()
        return int(self._socket.getsockname()[1])

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None
        self.is_open = False

    def _reconfigure_port(self, *args, **kwargs) -> None:
        pass  # a socket has no baud rate

    def _drain(self) -> None:
        """Move every datagram waiting in the socket into the buffer (never blocks)."""
        while True:
            try:
                data = self._socket.recv(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                raise SerialException(f"{self._port}: {exc}") from None
            if data:
                self._buffer += data if data.endswith(b"\n") else data + b"\n"

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        self._drain()
        return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        if size <= 0:
            return b""
        timeout = Timeout(self._timeout)
        self._cancel = False
        while True:
            self._drain()
            if self._buffer or timeout.expired() or self._cancel:
                break
            left = timeout.time_left()
            wait = POLL_S if left is None else max(0.0, min(POLL_S, left))
            try:
                select.select([self._socket], [], [], wait)
            except (OSError, ValueError):  # closed under us
                time.sleep(wait)
        out = bytes(self._buffer[:size])
        del self._buffer[:size]
        return out

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        return len(data)  # a listener sends nothing

    def reset_input_buffer(self) -> None:
        self._buffer.clear()

    def reset_output_buffer(self) -> None:
        pass

    def cancel_read(self) -> None:
        self._cancel = True

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
