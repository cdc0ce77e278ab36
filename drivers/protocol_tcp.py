"""``tcp://HOST:PORT``: pyserial's ``socket://`` client under the name marine networks use.

An NMEA multiplexer or a gyrocompass's network interface serves sentences to TCP clients
(``[nav] url = "tcp://HOST:PORT"``). The connection is pyserial's own socket port, with two
differences that suit a stream of sentences: what the server sent before the first read is
read, not discarded when the port opens, and a read that meets the end of the connection
returns what came before it (the next read raises), instead of dropping it with the error.
"""

from __future__ import annotations

import select
from urllib.parse import urlsplit, urlunsplit

from serial.serialutil import PortNotOpenError, SerialException, Timeout
from serial.urlhandler.protocol_socket import Serial as _SocketPort


class Serial(_SocketPort):
    """pyserial's ``socket://`` port, opened from a ``tcp://`` URL."""

    def open(self) -> None:
        self._closed_by_peer = False
        super().open()

    def from_url(self, url: str):
        parts = urlsplit(url)
        if parts.scheme == "tcp":
            url = urlunsplit(("socket", *parts[1:]))
        return super().from_url(url)

    def reset_input_buffer(self) -> None:
        pass  # sentences already sent are kept (pyserial's socket port drops them at open)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        if self._closed_by_peer:
            raise SerialException("socket disconnected")
        out = bytearray()
        timeout = Timeout(self._timeout)
        while len(out) < size and not timeout.expired():
            try:
                ready, _, _ = select.select([self._socket], [], [], timeout.time_left())
                if not ready:
                    break
                data = self._socket.recv(size - len(out))
            except (BlockingIOError, InterruptedError):
                continue
            except OSError as exc:
                raise SerialException(f"read failed: {exc}") from None
            if not data:  # the server closed: give what came first, raise at the next read
                self._closed_by_peer = True
                if not out:
                    raise SerialException("socket disconnected")
                break
            out += data
        return bytes(out)
