"""pyserial handler for ``replay://``: a capture file played back as if it were a serial port.

URL: ``replay:///abs/path/capture.bin?option=value&...`` (``replay://relative.bin`` also works).

Options:
- ``speed``: 1.0 (default) plays in real time, N plays N times faster, ``max`` as fast as read.
- ``rate``: data rate in Hz used for pacing (default 1000); with ``fmt`` it gives the byte
  rate: rate x frame length bytes per second, times ``speed``.
- ``fmt``: frame format name for pacing (default kvh-a).
- ``chunk``: ``random`` makes each read return a random 1..chunk_max bytes (as a UART driver
  might), an integer caps every read at that many bytes; default: reads are not capped.
- ``chunk_max``: upper bound for random chunks (default 512). ``seed``: random seed (default 0).
- ``eof``: what happens at the end: ``idle`` (default: a silent port; ``port.at_eof`` becomes
  True), ``error`` (SerialException, like an unplugged device) or ``loop`` (start over).

Writes are accepted and ignored (device commands have no effect on a capture).
"""

from __future__ import annotations

import os
import random
import time
from dataclasses import dataclass
from urllib.parse import parse_qs, unquote, urlsplit

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, Timeout

_OPTIONS = ("speed", "rate", "fmt", "chunk", "chunk_max", "seed", "eof")


@dataclass(frozen=True)
class ReplayOptions:
    path: str
    speed: float | None = 1.0  # None: as fast as possible
    rate_hz: float = 1000.0
    fmt: str = "kvh-a"
    chunk: int | str | None = None  # None, an int cap, or "random"
    chunk_max: int = 512
    seed: int = 0
    eof: str = "idle"

    @property
    def byte_rate(self) -> float | None:
        if self.speed is None:
            return None
        from .formats import get_format  # late: keeps pyserial's import of this module light

        return self.rate_hz * get_format(self.fmt).length * self.speed


def parse_replay_url(url: str) -> ReplayOptions:
    """Options of a replay:// URL; ValueError (pyserial's convention) when malformed."""
    parts = urlsplit(url)
    if parts.scheme.lower() != "replay":
        raise ValueError(f"expected a replay:// URL, not {url!r}")
    path = unquote(parts.netloc + parts.path)
    if not path:
        raise ValueError("replay:// URL names no capture file (replay:///path/to/capture.bin)")
    try:
        query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
    except ValueError:
        raise ValueError(f"cannot read the options of {url!r}") from None
    unknown = sorted(set(query) - set(_OPTIONS))
    if unknown:
        raise ValueError(f"unknown replay:// option {unknown[0]!r} (known: {', '.join(_OPTIONS)})")
    opt = {k: v[-1] for k, v in query.items()}
    kw: dict[str, object] = {"path": path}
    try:
        if "speed" in opt:
            kw["speed"] = None if opt["speed"].lower() == "max" else float(opt["speed"])
            if kw["speed"] is not None and not kw["speed"] > 0:  # type: ignore[operator]
                raise ValueError
        if "rate" in opt:
            kw["rate_hz"] = float(opt["rate"])
            if not kw["rate_hz"] > 0:  # type: ignore[operator]
                raise ValueError
        if "chunk" in opt:
            kw["chunk"] = "random" if opt["chunk"].lower() == "random" else int(opt["chunk"])
            if kw["chunk"] != "random" and kw["chunk"] < 1:  # type: ignore[operator]
                raise ValueError
        if "chunk_max" in opt:
            kw["chunk_max"] = int(opt["chunk_max"])
            if kw["chunk_max"] < 1:  # type: ignore[operator]
                raise ValueError
        if "seed" in opt:
            kw["seed"] = int(opt["seed"])
    except ValueError:
        raise ValueError(
            f"bad replay:// option value in {parts.query!r} (speed>0 or max, rate>0, "
            "chunk=random or a positive integer, chunk_max and seed integers)"
        ) from None
    if "fmt" in opt:
        kw["fmt"] = opt["fmt"]
    if "eof" in opt:
        if opt["eof"] not in ("idle", "error", "loop"):
            raise ValueError(f"replay:// eof must be idle, error or loop, not {opt['eof']!r}")
        kw["eof"] = opt["eof"]
    options = ReplayOptions(**kw)  # type: ignore[arg-type]
    if "fmt" in opt:
        try:
            options.byte_rate  # noqa: B018 - validates the format name
        except Exception as exc:  # DriverInputError, without importing it at module level
            raise ValueError(str(exc)) from None
    return options


class Serial(SerialBase):
    """A capture file served through pyserial's Serial interface."""

    def __init__(self, *args, **kwargs) -> None:
        self._file = None
        self._options: ReplayOptions | None = None
        self._size = 0
        self._delivered = 0
        self._t0 = 0.0
        self._rng = random.Random(0)
        self._cancel = False
        self.at_eof = False
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        options = parse_replay_url(self._port)
        try:
            self._file = open(options.path, "rb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise SerialException(
                exc.errno, f"cannot open replay capture {options.path}: {exc.strerror}"
            ) from None
        self._options = options
        self._size = os.fstat(self._file.fileno()).st_size
        self._delivered = 0
        self._rng = random.Random(options.seed)
        self._t0 = time.monotonic()
        self.at_eof = False
        self.is_open = True

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
        self.is_open = False

    def _reconfigure_port(self, *args, **kwargs) -> None:
        pass  # baud rate and framing mean nothing for a file

    def _file_left(self) -> int:
        if self._options is not None and self._options.eof == "loop" and self._size:
            return 1 << 62
        return self._size - self._delivered

    def _available(self) -> int:
        left = self._file_left()
        rate = self._options.byte_rate if self._options else None
        if rate is None:
            return left
        paced = int((time.monotonic() - self._t0) * rate) - self._delivered
        return max(0, min(left, paced))

    def _take(self, count: int) -> bytes:
        out = bytearray()
        while len(out) < count:
            chunk = self._file.read(count - len(out))
            if not chunk:
                if self._options.eof == "loop" and self._size:
                    self._file.seek(0)
                    continue
                break
            out += chunk
        self._delivered += len(out)
        return bytes(out)

    def _wait_for(self, missing: int, left: float | None) -> float:
        """How long to sleep before ``missing`` more bytes are due (a real port blocks the same
        way): the pacing time of those bytes, at most 50 ms so cancel_read() is seen soon, and
        never past the read timeout. Pacing one byte at a time would spin."""
        rate = self._options.byte_rate if self._options else None
        if rate is None or self._file_left() <= 0:
            wait = 0.01
        else:
            due = (self._delivered + missing) / rate
            wait = max(due - (time.monotonic() - self._t0), 0.0005)
        wait = min(wait, 0.05)
        return max(0.0, wait if left is None else min(wait, left))

    def arrival_time(self) -> float:
        """When the last byte delivered so far was due (host monotonic time): a replay is a
        device with a schedule, so a byte arrives when it is due, not when a held-up reader
        got round to it (a real port's bytes wait in the kernel the same way)."""
        rate = self._options.byte_rate if self._options else None
        now = time.monotonic()
        if rate is None:
            return now
        return min(now, self._t0 + self._delivered / rate)

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        return self._available()

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        if size <= 0:
            return b""
        options = self._options
        cap = size
        if options.chunk == "random":
            cap = min(size, self._rng.randint(1, options.chunk_max))
        elif options.chunk is not None:
            cap = min(size, options.chunk)
        timeout = Timeout(self._timeout)
        out = bytearray()
        self._cancel = False
        while True:
            take = min(cap - len(out), self._available())
            if take > 0:
                out += self._take(take)
            if len(out) >= cap or (out and options.chunk is not None):
                break
            if self._file_left() <= 0:
                self.at_eof = True
                if options.eof == "error":
                    if out:
                        break
                    raise SerialException("replay: end of capture")
            if timeout.expired() or self._cancel:
                break
            time.sleep(self._wait_for(cap - len(out), timeout.time_left()))
        return bytes(out)

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        return len(data)

    def reset_input_buffer(self) -> None:
        pass  # a capture is never discarded

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
