"""A reader thread that owns a port: reads, parses, delivers, and survives unplugging.

Any registered input format (drivers.registry): a binary format's parser is fed every read; a
line format's is fed whole lines (drivers.lines.LineSplitter carries a partial line across
reads), and a line it rejects is skipped and counted, not fatal: a serial line garbles a line
now and then, and a port opened mid-stream starts inside one.
"""

from __future__ import annotations

import logging
import math
import queue as queue_mod
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import serial

from .config import DEFAULT_CONFIG, DecoderConfig
from .errors import DriverInputError
from .formats import FrameFormat
from .frames import DecoderCounters, FrameBatch
from .lines import LineSplitter
from .registry import get_input_format
from .transport import DEFAULT_BAUD, check_url, open_serial, read_chunk, read_size_for

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReaderHealth:
    """A snapshot of the reader's state.

    running: the thread is alive. connected: the port is open (False while unplugged and
    being re-opened). last_frame_time / last_byte_time: host monotonic time (time.monotonic())
    of the last decoded frame / received byte, or None; seconds_since_last_frame /
    seconds_since_last_byte: their age when the snapshot was taken. disconnected_s: how long the
    port has been away (since the failure, or since start if it never opened), None while
    connected. reconnect_count: successful re-opens after the first open. last_error: the last
    port or delivery error as text (kept after a reconnect; last_error_time says when).
    diagnosis: a plain-words warning when the stream looks like another format
    (drivers.diagnose), else None. state: "stopped", "disconnected", "ended" (a replayed
    capture read to its end: nothing more will come), "silent" (open, but no byte for
    silence_s) or "ok"; problem: one plain-words sentence for any state but "ok" (what a
    service's /health shows when it reports itself degraded), else None. ended_s: how long
    ago the input ended, None before.
    """

    running: bool
    connected: bool
    last_frame_time: float | None
    reconnect_count: int
    counters: DecoderCounters
    last_error: str | None
    diagnosis: str | None
    dropped_batches: int
    last_byte_time: float | None = None
    seconds_since_last_byte: float | None = None
    seconds_since_last_frame: float | None = None
    disconnected_s: float | None = None
    last_error_time: float | None = None
    state: str = "ok"
    problem: str | None = None
    ended_s: float | None = None


class FrameReader:
    """Read ``url`` in a thread, parse, and hand each non-empty FrameBatch to ``on_batch``
    and/or put it on ``queue`` (never blocking: a full queue drops the batch and counts it).

    The format: ``fmt`` and ``config`` (a KVH frame format), or ``fmt`` an input format name
    with its ``options`` (e.g. ``"csv"``, ``{"columns": "accel_x=ax,...", "rate_hz": 100}``),
    or a ready ``parser`` (drivers.registry.StreamParser; ``fmt`` then names its format).

    On SerialException or OSError the port is closed, the partial frame dropped (sequence
    continuity kept, so lost frames show as a sequence gap), and the port re-opened after a
    bounded exponential back-off (backoff_initial doubling up to backoff_max). A URL whose
    scheme is unknown fails at construction (DriverInputError); a missing device is retried.

    A port that knows its input has ended (a ``replay://`` capture read to its end with
    ``eof=idle``: ``port.at_eof`` and nothing waiting) ends the stream: what the parser still
    holds (a last line without a newline, frames kept back) is delivered, then ``on_end`` is
    called once (in the reader thread) and the state is "ended". The thread keeps running (an ended replay is not a
    fault a restart would mend).
    """

    def __init__(
        self,
        url: str,
        fmt: str | FrameFormat = "kvh-a",
        config: DecoderConfig = DEFAULT_CONFIG,
        *,
        on_batch: Callable[[FrameBatch], None] | None = None,
        queue: queue_mod.Queue | None = None,
        baudrate: int = DEFAULT_BAUD,
        read_size: int = 4096,
        timeout: float = 0.05,
        backoff_initial: float = 0.05,
        backoff_max: float = 2.0,
        name: str = "frame-reader",
        latency: float = 0.05,
        silence_s: float = 1.0,
        options: dict | None = None,
        parser: object | None = None,
        on_end: Callable[[], None] | None = None,
    ) -> None:
        check_url(url, must_exist=False)
        if parser is None:
            parser = _make_parser(fmt, config, options or {}, url)
        spec = _input_spec(fmt)
        framing = "binary" if spec is None else spec.framing
        if spec is not None:
            if spec.inputs != 1:
                raise DriverInputError(
                    f"format {spec.name} is read from {spec.inputs} files side by side; a "
                    "port carries one stream"
                )
        self._parser = parser
        self._last_stamp = -math.inf  # the host time given to the last read's bytes
        self._lines = LineSplitter() if framing == "lines" else None
        self.lines_skipped = 0
        self.url = url
        self.baudrate = baudrate
        self.read_size = read_size
        self.timeout = timeout
        self.silence_s = silence_s
        # Each read waits for about `latency` s of data at the configured rate (bounded by
        # `timeout`): ~20 reads/s at the defaults, whatever the rate, instead of one per byte.
        # A line format's parser may not know its byte rate: then reads wait on the timeout.
        self.byte_rate = getattr(parser, "byte_rate", None) or 0.0
        self.min_read = read_size_for(self.byte_rate, latency, read_size)
        self.backoff_initial = backoff_initial
        self.backoff_max = backoff_max
        self._on_batch = on_batch
        self._on_end = on_end
        self._ended_at: float | None = None  # host time the input ended (replay at its end)
        self._queue = queue
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._port = None
        self._connected = False
        self._ever_connected = False
        self._reconnects = 0
        self._last_frame_time: float | None = None
        self._last_byte_time: float | None = None
        self._last_error: str | None = None
        self._last_error_time: float | None = None
        self._away_since: float | None = time.monotonic()
        self._connected_at: float | None = None
        self._dropped = 0
        self._skip_first = False
        self._skip_reason = ""

    def start(self) -> FrameReader:
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> bool:
        """Ask the thread to finish and wait up to ``timeout`` s; True if it has ended.

        Called from ``on_batch`` (the reader thread itself) it only asks, returns False, and the
        thread ends after the callback returns.
        """
        self._stop.set()
        if threading.current_thread() is self._thread:
            return False  # a thread cannot join itself
        port = self._port
        if port is not None:
            try:
                port.cancel_read()
            except Exception:  # noqa: BLE001 - best effort wake-up; the read timeout also ends it
                pass
        if self._thread.is_alive():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    def __enter__(self) -> FrameReader:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def health(self) -> ReaderHealth:
        with self._lock:
            now = time.monotonic()
            counters = self._parser.counters.copy()
            if self._lines is not None:
                counters.bytes_pending = self._lines.pending
            running = self._thread.is_alive()
            connected = self._connected
            last_byte = self._last_byte_time
            quiet_since = last_byte if last_byte is not None else self._connected_at
            away = None if connected or self._away_since is None else now - self._away_since
            if not running:
                state, problem = "stopped", f"the reader of {self.url} is not running"
            elif not connected:
                state = "disconnected"
                problem = f"{self.url} is disconnected ({away:.1f} s)" + (
                    f": {self._last_error}" if self._last_error else ""
                )
            elif self._ended_at is not None:
                state = "ended"
                problem = (
                    f"the capture has been replayed to its end ({now - self._ended_at:.1f} s "
                    "ago): no more frames will come"
                )
            elif quiet_since is not None and now - quiet_since > self.silence_s:
                state = "silent"
                problem = f"{self.url} is open but has sent nothing for {now - quiet_since:.1f} s"
            else:
                state, problem = "ok", None
            return ReaderHealth(
                running=running,
                connected=connected,
                last_frame_time=self._last_frame_time,
                reconnect_count=self._reconnects,
                counters=counters,
                last_error=self._last_error,
                diagnosis=self._diagnosis(),
                dropped_batches=self._dropped,
                last_byte_time=last_byte,
                seconds_since_last_byte=None if last_byte is None else now - last_byte,
                seconds_since_last_frame=None
                if self._last_frame_time is None
                else now - self._last_frame_time,
                disconnected_s=away,
                last_error_time=self._last_error_time,
                state=state,
                problem=problem,
                ended_s=None if self._ended_at is None else now - self._ended_at,
            )

    def _diagnosis(self) -> str | None:
        """The parser's word on a mis-set format (binary formats), or the last skipped line."""
        diagnosis = getattr(self._parser, "diagnosis", None)
        if diagnosis is not None:
            return diagnosis()
        if self.lines_skipped:
            return f"{self.lines_skipped} line(s) skipped as unreadable; last: {self._skip_reason}"
        return None

    def _set_error(self, text: str) -> None:
        """Record an error (call with the lock held)."""
        self._last_error = text
        self._last_error_time = time.monotonic()

    def _open(self) -> bool:
        try:
            port = open_serial(self.url, baudrate=self.baudrate, timeout=self.timeout)
        except (serial.SerialException, OSError) as exc:  # e.g. unplugged: retry
            with self._lock:
                self._set_error(f"cannot open {self.url}: {exc}")
            return False
        except Exception as exc:  # noqa: BLE001 - malformed URL options: retrying cannot help
            with self._lock:
                self._set_error(f"bad port URL {self.url!r}: {type(exc).__name__}: {exc}")
            self._stop.set()
            return False
        with self._lock:
            self._port = port
            self._connected = True
            self._connected_at = time.monotonic()
            self._away_since = None
            self._ended_at = None  # re-opened: the input starts again
            if self._ever_connected:
                self._reconnects += 1
                log.info("%s: re-opened (reconnect %d)", self.url, self._reconnects)
            self._ever_connected = True
        return True

    def _drop_port(self, exc: BaseException | None) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001 - the port is already broken
                pass
        with self._lock:
            if self._connected:
                self._away_since = time.monotonic()
            self._connected = False
            if exc is not None:
                self._set_error(f"{self.url}: {exc}")
                log.warning("%s: port lost (%s); re-opening", self.url, exc)
            if self._lines is not None:
                self._lines.drop()  # the line was cut; the next one after re-opening may be too
                self._skip_first = True
            self._parser.flush()

    def _deliver(self, batch: FrameBatch) -> None:
        if self._on_batch is not None:
            try:
                self._on_batch(batch)
            except Exception as exc:  # noqa: BLE001 - a consumer bug must not kill the reader
                log.exception("frame callback failed")
                with self._lock:
                    self._set_error(f"callback: {type(exc).__name__}: {exc}")
        if self._queue is not None:
            try:
                self._queue.put_nowait(batch)
            except queue_mod.Full:
                with self._lock:
                    self._dropped += 1

    def _parse(self, data: bytes, now: float) -> FrameBatch:
        """Feed the parser (call with the lock held); a line format's bad lines are skipped."""
        if self._lines is None:
            return self._parser.feed(data, host_time=now)
        block = self._lines.feed(data)
        if self._skip_first and block:  # re-opened: the first line may be the tail of one
            block = block[block.index(b"\n") + 1 :]
            self._skip_first = False
        if not block:
            return FrameBatch.empty(self._parser.name)
        try:
            return self._parser.feed(block, host_time=now)
        except DriverInputError:
            pass
        batches = []  # one line at a time: keep the good ones
        for line in block.splitlines(keepends=True):
            try:
                batches.append(self._parser.feed(line, host_time=now))
            except DriverInputError as exc:
                self.lines_skipped += 1
                self._skip_reason = str(exc)
        return FrameBatch.concat(batches) if batches else FrameBatch.empty(self._parser.name)

    def _arrival(self, port: serial.SerialBase, now: float) -> float:
        """When the last byte of a read came off the wire: ``now`` less the wire time of the
        bytes still waiting behind it (at the device's byte rate), never before the previous
        read's. A reader held up (a loaded machine) drains the backlog in reads of at most
        ``read_size``; dated ``now``, each would make the stall look like lost frames, and a
        stall of 64 frame periods like a whole wrap of the 7-bit sequence number (128 frames
        counted lost, time_s shifted, where nothing was lost). A replay (drivers.protocol_replay)
        gives its own schedule, which stays right when it plays faster than the device."""
        stamp = now
        scheduled = getattr(port, "arrival_time", None)  # a replay knows when bytes were due
        try:
            if callable(scheduled):
                stamp = float(scheduled())
            elif self.byte_rate:
                stamp = now - port.in_waiting / self.byte_rate
        except (OSError, serial.SerialException):
            stamp = now
        stamp = max(stamp, self._last_stamp)
        self._last_stamp = stamp
        return stamp

    def _end_of_input(self) -> None:
        """The port's input has ended: deliver what the parser still holds (a last line
        without a newline, frames kept back to judge the bytes or the time steps after them),
        mark the state "ended" and call ``on_end``."""
        now = time.monotonic()
        with self._lock:
            self._ended_at = now
            tail = self._lines.flush() if self._lines is not None else b""
            # the last line's bytes came with the last read: its arrival time
            came = self._last_stamp if math.isfinite(self._last_stamp) else now
            parts = [self._parse(tail + b"\n", came)] if tail.strip() else []
            parts.append(self._parser.flush())
            parts = [p for p in parts if p is not None and len(p)]
            batch = FrameBatch.concat(parts) if parts else None
            if batch is not None:
                self._last_frame_time = now
        if batch is not None:
            self._deliver(batch)
        log.info("%s: end of input", self.url)
        if self._on_end is not None:
            try:
                self._on_end()
            except Exception as exc:  # noqa: BLE001 - a consumer bug must not kill the reader
                log.exception("end-of-input callback failed")
                with self._lock:
                    self._set_error(f"end callback: {type(exc).__name__}: {exc}")

    def _run(self) -> None:
        delay = self.backoff_initial
        try:
            while not self._stop.is_set():
                if self._port is None:
                    if not self._open():
                        self._stop.wait(delay)
                        delay = min(delay * 2, self.backoff_max)
                        continue
                port = self._port
                try:
                    data = read_chunk(
                        port, self.min_read, self.read_size, self.byte_rate, self._stop.wait
                    )
                except Exception as exc:  # noqa: BLE001 - any port failure: close and re-open
                    if not isinstance(exc, serial.SerialException | OSError):
                        log.exception("%s: unexpected error from the port", self.url)
                    self._drop_port(exc)
                    # A port that opens but fails at once (a flapping device) backs off too:
                    # the delay restarts only once data has come through.
                    self._stop.wait(delay)
                    delay = min(delay * 2, self.backoff_max)
                    continue
                if not data:
                    if self._ended_at is None and _input_ended(port):
                        self._end_of_input()
                    continue
                delay = self.backoff_initial
                now = time.monotonic()
                stamp = self._arrival(port, now)
                with self._lock:
                    self._last_byte_time = now
                    batch = self._parse(data, stamp)
                    if len(batch):
                        self._last_frame_time = now
                if len(batch):
                    self._deliver(batch)
        finally:
            self._drop_port(None)


def _input_ended(port: object) -> bool:
    """The port says its input has ended (``at_eof``, as a replay:// port at the end of its
    capture with ``eof=idle``) and nothing is left to read. A serial port never does."""
    try:
        return getattr(port, "at_eof", False) is True and not port.in_waiting
    except Exception:  # noqa: BLE001 - a port failing here fails the next read too
        return False


def _make_parser(fmt: str | FrameFormat, config: DecoderConfig, options: dict, url: str):
    """The parser of a format: a KVH frame format with its DecoderConfig, or any input format
    with its options."""
    from .kvh_stream import kvh_parser

    spec = _input_spec(fmt)
    if spec is None:
        return kvh_parser(fmt, source=url, config=config)
    if spec.factory() is kvh_parser and not options:
        return kvh_parser(spec.name, source=url, config=config)
    return spec.make_parser(source=url, **options)


def _input_spec(fmt: str | FrameFormat):
    """The registered input format, or None for a frame format only (e.g. kvh-bit)."""
    if isinstance(fmt, FrameFormat):
        return None
    try:
        return get_input_format(fmt)
    except DriverInputError:
        from .formats import get_format

        get_format(fmt)  # unknown everywhere: its error names the frame formats
        return None
