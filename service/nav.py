"""The ship's sensors in the daemon (``[nav]``): the NMEA reader, the track, and each window's
ship state joined by time.

:class:`ShipSensors` owns a :class:`drivers.nav_reader.NavReader` (a thread that keeps a
:class:`drivers.nmea.NavTrack` up to date and reopens a link that drops) and a
:class:`DeviceClock`. The reader stamps each sentence with the host's monotonic clock on arrival,
as :class:`drivers.FrameReader` stamps the IMU's frames (``FrameBatch.host_time_s``); the
pipeline gives the clock every batch it takes, so a window's device times (``start_s``, ``end_s``,
s from the first frame) become host times, and the track's fixes over them are the ship's state
over the window (:meth:`ShipSensors.over`). recal sees only the numbers
(:mod:`recal.detect.underway`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

log = logging.getLogger("recal.nav")

#: Fixes kept, s of host time: a window is decided up to about 20 minutes after it ends (the
#: hull detector's look-ahead) and lasts up to 15.
TRACK_AGE_S = 3 * 3600.0
#: One device-to-host time pair kept per this much device time, s, and how many.
CLOCK_STEP_S, CLOCK_PAIRS = 1.0, 4 * 3600


class DeviceClock:
    """Device time (s from the session's first frame) to host monotonic time, from the frames'
    own pairs (device ``time_s``, host ``host_time_s`` of the read that completed them).

    The host time of a frame is its arrival, later than its true time by the link's latency; a
    window's host span is what the ship's sensors were sampled over, within that latency (well
    under a second, against windows of minutes). Between pairs the map is linear; past the last
    one it goes on at the last slope (1 s per s)."""

    def __init__(self) -> None:
        self._t0: float | None = None  # device time of the first frame
        self._pairs: deque[tuple[float, float]] = deque(maxlen=CLOCK_PAIRS)
        self._lock = threading.Lock()

    def observe(self, time_s: np.ndarray, host_time_s: np.ndarray) -> None:
        """Take a batch's frame times (NaN host times are skipped)."""
        t = np.asarray(time_s, dtype=float)
        h = np.asarray(host_time_s, dtype=float)
        ok = np.isfinite(t) & np.isfinite(h)
        if not ok.any():
            return
        t, h = t[ok], h[ok]
        with self._lock:
            if self._t0 is None:
                self._t0 = float(t[0])
            # the batch's last frame: the read that completed it is what its host time dates
            rel = float(t[-1]) - self._t0
            last = self._pairs[-1][0] if self._pairs else -math.inf
            if rel >= last + CLOCK_STEP_S or (not self._pairs and rel >= 0.0):
                self._pairs.append((rel, float(h[-1])))

    @property
    def first_time_s(self) -> float | None:
        """The device time of the first frame observed, None before any."""
        with self._lock:
            return self._t0

    def hosts(self, time_s: np.ndarray) -> np.ndarray | None:
        """The host times of frames at device times ``time_s`` (as the batches give them, not
        relative to the first frame), vectorised; None before any frame."""
        t0 = self.first_time_s
        return None if t0 is None else self._hosts(np.asarray(time_s, dtype=float) - t0)

    def _hosts(self, rel: np.ndarray) -> np.ndarray | None:
        """Host times of device times ``rel`` (s from the first frame): linear between pairs,
        on at 1 s per s past either end; None before any frame."""
        with self._lock:
            if not self._pairs:
                return None
            dev = np.array([p[0] for p in self._pairs])
            host = np.array([p[1] for p in self._pairs])
        out = np.interp(rel, dev, host)
        out = np.where(rel > dev[-1], host[-1] + (rel - dev[-1]), out)
        return np.where(rel < dev[0], host[0] - (dev[0] - rel), out)

    def host(self, device_s: float) -> float | None:
        """The host time of device time ``device_s`` (s from the first frame), None before any
        frame."""
        out = self._hosts(np.array([float(device_s)]))
        return None if out is None else float(out[0])


class ShipSensors:
    """``[nav]`` in the daemon: the reader, the track, the clock and the underway rule's
    threshold. ``reader=False`` builds everything but the thread (a test feeds the track)."""

    def __init__(
        self,
        settings: Any,
        *,
        reader: bool = True,
        on_latitude: Callable[[float], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        from drivers.nav_reader import NavReader
        from drivers.nmea import NavTrack

        self.settings = settings
        self.track = NavTrack(max_age_s=TRACK_AGE_S)
        self.clock = DeviceClock()
        #: ``[nav] log``: a logged talker beside a replayed capture, on the capture's own clock
        #: (its first sentence at the first frame): windows join it by device time
        self.on_device_clock = getattr(settings, "log", None) is not None
        self.max_sog_kn = float(settings.max_sog_kn)
        #: called (in the reader's thread) with each newest latitude the sentences give
        self.on_latitude = on_latitude
        self.started = False
        self.reader = None
        if self.on_device_clock:
            from pathlib import Path

            from drivers.nmea import read_log

            self.track = read_log(Path(settings.log).read_bytes(), source=settings.log).track
        elif reader:
            self.reader = NavReader(settings.url, self.track, on_fixes=self._fixes,
                                    baudrate=settings.baudrate, clock=clock)  # fmt: skip

    def start(self) -> None:
        if self.reader is not None and not self.started:
            self.reader.start()
        if self.on_device_clock and not self.started and self.on_latitude is not None:
            latest = self.track.latest_position()  # a log's latitude is known from the start
            if latest is not None:
                self.on_latitude(latest[1])
        self.started = True

    def stop(self) -> None:
        if self.reader is not None:
            self.reader.stop()

    def _fixes(self, fixes: Sequence[Any]) -> None:
        if self.on_latitude is None:
            return
        lats = [f.lat for f in fixes if math.isfinite(f.lat)]
        if lats:
            self.on_latitude(lats[-1])

    def latitude_deg(self) -> float | None:
        """The newest latitude the ship's sensors gave, or None."""
        latest = self.track.latest_position()
        return None if latest is None else latest[1]

    def observe(self, batch: Any) -> None:
        """A batch of frames the pipeline takes (its device and host times)."""
        self.clock.observe(batch.time_s, batch.host_time_s)

    def heading_of(self, time_s: np.ndarray) -> np.ndarray | None:
        """The ship's true heading at each frame (device times as the batches give them), deg,
        NaN where the track has none near; None when no heading has come at all."""
        from drivers.nmea import heading_at

        hosts = self._track_times(time_s)
        if hosts is None:
            return None
        psi = heading_at(self.track, hosts)
        return psi if np.isfinite(psi).any() else None

    def over(self, windows: Sequence[Any]) -> list[Any]:
        """The ship over each window (drivers.nmea.NavWindow), None where the track does not
        cover it."""
        out = []
        for w in windows:
            if self.on_device_clock:  # window times count from the first frame, as the log
                out.append(self.track.window(w.start_s, w.end_s))
                continue
            h0, h1 = self.clock.host(w.start_s), self.clock.host(w.end_s)
            out.append(None if h0 is None or h1 is None else self.track.window(h0, h1))
        return out

    def _track_times(self, time_s: np.ndarray) -> np.ndarray | None:
        """Frame device times (as the batches give them) on the track's clock: host times, or
        for a log, seconds from the first frame."""
        if not self.on_device_clock:
            return self.clock.hosts(time_s)
        t0 = self.clock.first_time_s
        return None if t0 is None else np.asarray(time_s, dtype=float) - t0

    @property
    def alive(self) -> bool:
        return self.reader is None or self.reader.health().running

    def health(self) -> dict[str, Any]:
        """The ``nav`` block of ``/health``."""
        out: dict[str, Any] = {"url": self.settings.url, "log": getattr(self.settings, "log", None),
                               "max_sog_kn": self.max_sog_kn,
                               "fixes": self.track.total,
                               "latitude_deg": self.latitude_deg()}  # fmt: skip
        if self.reader is not None:
            h = self.reader.health()
            out |= {
                "state": h.state,
                "problem": h.problem,
                "connected": h.connected,
                "reconnect_count": h.reconnect_count,
                "seconds_since_last_fix": h.seconds_since_last_fix,
                "last_error": h.last_error,
                "last_skipped": h.last_skipped,
                "counters": vars(h.counters),
            }
        return out


def working_latitude(settings: Any, positions: Any) -> float | None:
    """The latitude a calibration of ``positions`` is computed at: the mean of the windows'
    ``latitude_deg`` (the ship's sensors) where any has one, else ``[site] latitude_deg`` (45
    for a still unit without ``[nav]``, :attr:`service.config.Settings.site_latitude_deg`);
    None with neither (a hull-fixed unit whose ship's sensors have given nothing yet)."""
    lat = positions.columns.get("latitude_deg") if positions is not None else None
    if lat is not None:
        lat = np.asarray(lat, dtype=float)
        if np.isfinite(lat).any():
            return float(np.nanmean(lat))
    return settings.site_latitude_deg


#: Why a calibration cannot run without a latitude (the scheduler and triggers say it).
NO_LATITUDE = (
    "no latitude: the stored windows carry none (the ship's sensors, [nav], have not covered "
    "any yet) and [site] latitude_deg is unset"
)
