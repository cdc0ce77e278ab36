"""A thread that owns the ship's NMEA link: reads, parses, keeps a :class:`NavTrack`, and
survives the link going away.

The link is any URL :mod:`drivers.transport` opens: a serial port at the NMEA baud rate (4800 or
38400), ``udp://:10110`` (the marine broadcast default, :mod:`drivers.protocol_udp`),
``tcp://HOST:PORT`` (:mod:`drivers.protocol_tcp`), ``socket://``, ``replay://``. Every read is
stamped with the host's monotonic clock when it returns (``time.monotonic()``, the clock
:class:`drivers.FrameReader` dates the IMU's frames with), so a sentence and a frame that arrive
together carry the same time. A line that cannot be read is counted and skipped
(:class:`drivers.nmea.NmeaParser`); a link that fails is closed, logged and reopened after a
bounded exponential back-off; nothing here ends the thread but :meth:`NavReader.stop`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import serial

from .nmea import NavFix, NavTrack, NmeaCounters, NmeaParser
from .transport import check_url, open_serial, read_chunk

log = logging.getLogger(__name__)

#: The NMEA 0183 standard's baud rate (high-speed talkers use 38400).
NMEA_BAUD = 4800


@dataclass(frozen=True)
class NavHealth:
    """A snapshot of the reader: ``state`` "ok", "silent" (open, no fix for ``silence_s``),
    "disconnected" or "stopped", with ``problem`` in plain words for any state but "ok";
    counters of the parser; the age of the last fix and of the last byte (s, None before any);
    the newest position; reconnects after the first open; the last link error."""

    running: bool
    connected: bool
    state: str
    problem: str | None
    counters: NmeaCounters
    fixes: int
    seconds_since_last_fix: float | None
    seconds_since_last_byte: float | None
    latitude_deg: float | None
    reconnect_count: int
    last_error: str | None
    last_skipped: str | None


class NavReader:
    """Read ``url`` in a thread, add every fix to ``track`` (created when not given) and hand
    each read's fixes to ``on_fixes`` (a consumer's exception is logged, never fatal).

    ``clock`` stamps the reads (time.monotonic, as the IMU's frames); ``silence_s``: no fix this
    long on an open link is "silent" in :meth:`health`.
    """

    def __init__(
        self,
        url: str,
        track: NavTrack | None = None,
        *,
        on_fixes: Callable[[list[NavFix]], None] | None = None,
        baudrate: int = NMEA_BAUD,
        timeout: float = 0.1,
        backoff_initial: float = 0.1,
        backoff_max: float = 10.0,
        silence_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
        name: str = "nav-reader",
    ) -> None:
        check_url(url, must_exist=False)
        self.url = url
        self.track = track if track is not None else NavTrack()
        self.parser = NmeaParser(source=url)
        self.baudrate = baudrate
        self.timeout = timeout
        self.backoff_initial = backoff_initial
        self.backoff_max = backoff_max
        self.silence_s = silence_s
        self._clock = clock
        self._on_fixes = on_fixes
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._port = None
        self._connected = False
        self._ever_connected = False
        self._reconnects = 0
        self._last_error: str | None = None
        self._last_fix: float | None = None
        self._last_byte: float | None = None
        self._opened_at: float | None = None
        self._away_since: float | None = clock()

    def start(self) -> NavReader:
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> bool:
        """Ask the thread to finish and wait up to ``timeout`` s; True if it has ended."""
        self._stop.set()
        port = self._port
        if port is not None:
            try:
                port.cancel_read()
            except Exception:  # noqa: BLE001 - best effort; the read timeout also ends it
                pass
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout)
        return not self._thread.is_alive()

    def __enter__(self) -> NavReader:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def port(self):
        """The open port (None while away): a test asks a ``udp://...:0`` port its number."""
        return self._port

    def health(self) -> NavHealth:
        with self._lock:
            now = self._clock()
            running = self._thread.is_alive()
            latest = self.track.latest_position()
            quiet_since = self._last_fix if self._last_fix is not None else self._opened_at
            if not running:
                state, problem = "stopped", f"the reader of {self.url} is not running"
            elif not self._connected:
                away = 0.0 if self._away_since is None else now - self._away_since
                state = "disconnected"
                problem = f"{self.url} is disconnected ({away:.1f} s)" + (
                    f": {self._last_error}" if self._last_error else ""
                )
            elif quiet_since is not None and now - quiet_since > self.silence_s:
                state = "silent"
                problem = f"{self.url} is open but has given no fix for {now - quiet_since:.1f} s"
            else:
                state, problem = "ok", None
            return NavHealth(
                running=running,
                connected=self._connected,
                state=state,
                problem=problem,
                counters=self.parser.counters.copy(),
                fixes=self.track.total,
                seconds_since_last_fix=None if self._last_fix is None else now - self._last_fix,
                seconds_since_last_byte=None if self._last_byte is None else now - self._last_byte,
                latitude_deg=None if latest is None else latest[1],
                reconnect_count=self._reconnects,
                last_error=self._last_error,
                last_skipped=self.parser.last_problem,
            )

    def _open(self) -> bool:
        try:
            port = open_serial(self.url, baudrate=self.baudrate, timeout=self.timeout)
        except Exception as exc:  # noqa: BLE001 - unplugged, refused, bad option: retry, logged
            with self._lock:
                first = self._last_error is None
                self._last_error = f"cannot open {self.url}: {exc}"
            if first:
                log.warning("nav: %s", self._last_error)
            return False
        with self._lock:
            self._port = port
            self._connected = True
            self._opened_at = self._clock()
            self._away_since = None
            if self._ever_connected:
                self._reconnects += 1
                log.info("nav: %s re-opened (reconnect %d)", self.url, self._reconnects)
            else:
                log.info("nav: reading %s", self.url)
            self._ever_connected = True
        return True

    def _drop(self, exc: BaseException | None) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001 - the port is already broken
                pass
        with self._lock:
            if self._connected:
                self._away_since = self._clock()
            self._connected = False
            self.parser.drop()  # the line was cut
            if exc is not None:
                self._last_error = f"{self.url}: {exc}"
                log.warning("nav: link %s lost (%s); re-opening", self.url, exc)

    def _run(self) -> None:
        delay = self.backoff_initial
        try:
            while not self._stop.is_set():
                if self._port is None:
                    if not self._open():
                        self._stop.wait(delay)
                        delay = min(2.0 * delay, self.backoff_max)
                        continue
                try:
                    data = read_chunk(self._port, 1, 4096)
                except Exception as exc:  # noqa: BLE001 - any link failure: close and re-open
                    if not isinstance(exc, serial.SerialException | OSError):
                        log.exception("nav: unexpected error from %s", self.url)
                    self._drop(exc)
                    self._stop.wait(delay)
                    delay = min(2.0 * delay, self.backoff_max)
                    continue
                if not data:
                    continue
                delay = self.backoff_initial
                now = self._clock()
                with self._lock:
                    self._last_byte = now
                    fixes = self.parser.feed(data, host_time=now)
                if fixes:
                    self.track.add(fixes)
                    with self._lock:
                        self._last_fix = now
                    if self._on_fixes is not None:
                        try:
                            self._on_fixes(fixes)
                        except Exception:  # noqa: BLE001 - a consumer bug must not end the reader
                            log.exception("nav: fix callback failed")
        finally:
            self._drop(None)
