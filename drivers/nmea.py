"""The ship's own sensors over NMEA 0183: GNSS position and speed, gyrocompass heading.

A second input stream beside the IMU's (shared/spec/conventions.md section 12): GGA and RMC give
the position (and GGA the height), RMC and VTG the speed and course over ground, HDT and THS the
true heading, from any talker (GP, GN, HE, IN, ...). The sentences are parsed by ``pynmeagps``, a
maintained parser; this module only picks the sentences and fields it needs, turns them into
:class:`NavFix` rows and keeps them in a :class:`NavTrack`, whose :meth:`NavTrack.window` gives
what a static window needs of the ship: mean latitude, mean speed over ground, mean true heading
(circular) and the net displacement.

Why it is not in the input-format registry (:mod:`drivers.registry`): a registered format is an
IMU's frame format, a parser whose output is a :class:`drivers.FrameBatch` of gyro and accel
samples, chosen by ``[device] format`` and ``--format``. NMEA is another instrument on another
link (``[nav] url``, ``--nmea``), read beside the IMU and never instead of it, and its rows are
positions and headings, not samples: registering it would offer ``format = "nmea"`` for the
IMU, which can never work.

:class:`NmeaParser` is separated from I/O as the IMU parsers are: feed it bytes (a serial read, a
datagram, a file chunk) or whole lines with the time they arrived; it returns the fixes those
lines complete. A bad checksum, an unreadable line or a sentence without a fix is counted
(:class:`NmeaCounters`) and skipped, never raised: a serial line garbles a sentence now and then,
and a port opened mid-stream starts inside one. :func:`read_log` reads a whole log (lines as
received) and dates its sentences by the UTC they carry. :func:`epoch_sentences` writes the
sentences of one fix (the simulator's ship), with pynmeagps's own message classes.

The live reader (a thread that owns the link and reopens it) is :mod:`drivers.nav_reader`.
"""

from __future__ import annotations

import datetime as dt
import math
import threading
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

from .errors import DriverInputError
from .lines import LineSplitter

#: Sentence formatters read (any talker); every other sentence is counted as ignored.
SENTENCES = ("GGA", "RMC", "VTG", "HDT", "THS")
#: WGS-84 semi-major axis and first eccentricity squared: the local radii of curvature that turn
#: latitude and longitude differences into metres.
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
#: Longest gap between two position fixes (and from a window's ends to the nearest fix) for the
#: track to count as covering a window, s.
MAX_GAP_S = 30.0
#: Metres per second in a knot.
KNOT_M_S = 1852.0 / 3600.0
_NAN = math.nan


@dataclass(frozen=True)
class NavFix:
    """What one sentence says. ``time_s``: when it arrived (the caller's clock: the daemon gives
    host monotonic time, as its IMU frames get) or, from :func:`read_log`, s from the log's first
    sentence; ``utc`` / ``date``: the UTC time of day and date the sentence carries (GGA, RMC),
    else None. Degrees (north, east positive), metres above the WGS-84 ellipsoid (GGA: altitude
    plus geoid separation), knots; NaN where the sentence does not carry a field."""

    time_s: float
    talker: str
    sentence: str
    utc: dt.time | None = None
    date: dt.date | None = None
    lat: float = _NAN
    lon: float = _NAN
    height: float = _NAN
    sog_kn: float = _NAN
    cog: float = _NAN
    heading_deg: float = _NAN


@dataclass
class NmeaCounters:
    """What the parser has seen. ``lines``: non-empty lines; ``fixes``: sentences that gave a
    :class:`NavFix`; ``ignored``: well-formed sentences of other kinds (GSV, proprietary, AIS);
    ``bad_checksum``: a checksum that does not match; ``garbage``: not a sentence, no checksum,
    or fields that cannot be read; ``no_fix``: a sentence saying it has no valid data (GGA
    quality 0, RMC status V, VTG/THS mode N or V, empty fields)."""

    lines: int = 0
    fixes: int = 0
    ignored: int = 0
    bad_checksum: int = 0
    garbage: int = 0
    no_fix: int = 0

    def copy(self) -> NmeaCounters:
        return NmeaCounters(**asdict(self))

    @property
    def skipped(self) -> int:
        """Lines that were meant to be read and could not be (bad checksum or garbage)."""
        return self.bad_checksum + self.garbage


def _num(value: object) -> float:
    """A pynmeagps field as a float; its empty field ("") and anything unreadable as NaN."""
    if value is None or value == "":
        return _NAN
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return _NAN


def _time(value: object) -> dt.time | None:
    return value if isinstance(value, dt.time) else None


def _date(value: object) -> dt.date | None:
    return value if isinstance(value, dt.date) else None


class NmeaParser:
    """Bytes or lines in, :class:`NavFix` rows out (see the module docstring); no I/O.

    ``feed(data, host_time)`` takes any bytes (a partial line waits for the next call) and
    returns the fixes of the lines they complete, each stamped ``host_time``; ``feed_line`` takes
    one line; ``flush`` reads a last line without a newline. ``counters`` says what was read;
    ``last_problem`` the last line skipped and why.
    """

    def __init__(self, source: str = "<nmea>") -> None:
        self.source = source
        self.counters = NmeaCounters()
        self.last_problem: str | None = None
        self._lines = LineSplitter(max_line=4096)  # NMEA lines are at most 82 characters

    def feed(self, data: bytes, host_time: float = _NAN) -> list[NavFix]:
        block = self._lines.feed(data)
        return self._block(block, host_time) if block else []

    def flush(self, host_time: float = _NAN) -> list[NavFix]:
        tail = self._lines.flush()
        return self._block(tail, host_time) if tail.strip() else []

    def drop(self) -> None:
        """Forget a partial line (the link was cut: what follows is another line)."""
        self._lines.drop()

    def _block(self, block: bytes, host_time: float) -> list[NavFix]:
        out = []
        for line in block.splitlines():
            fix = self.feed_line(line, host_time)
            if fix is not None:
                out.append(fix)
        return out

    def feed_line(self, line: bytes | str, host_time: float = _NAN) -> NavFix | None:
        """One line (with or without its CR LF; text before the ``$``, such as a logger's time
        stamp or an NMEA 4 tag block, is ignored); the fix it gives, or None."""
        from pynmeagps import NMEAMessageError, NMEAParseError, NMEAReader, NMEATypeError

        raw = line.encode("ascii", "replace") if isinstance(line, str) else bytes(line)
        raw = raw.strip()
        if not raw:
            return None
        self.counters.lines += 1
        start = raw.find(b"$")
        if start < 0:
            if raw.startswith(b"!"):  # AIS and other encapsulated sentences
                self.counters.ignored += 1
                return None
            return self._skip("garbage", raw, "not an NMEA sentence")
        raw = raw[start:]
        head = raw[1:6].decode("ascii", "replace")
        if len(head) < 5 or head.startswith("P") or head[2:5] not in SENTENCES:
            if len(head) < 5 or not head.isalnum():
                return self._skip("garbage", raw, "not an NMEA sentence")
            self.counters.ignored += 1  # a sentence this reader does not need
            return None
        if b"*" not in raw:
            return self._skip("garbage", raw, "no checksum")
        try:
            msg = NMEAReader.parse(raw + b"\r\n", validate=1)
        except NMEAParseError as exc:
            kind = "bad_checksum" if "checksum" in str(exc).lower() else "garbage"
            return self._skip(kind, raw, str(exc))
        except (NMEAMessageError, NMEATypeError, ValueError, TypeError, IndexError) as exc:
            return self._skip("garbage", raw, f"{type(exc).__name__}: {exc}")
        if msg is None:
            return self._skip("garbage", raw, "not an NMEA sentence")
        try:
            fix = _fix(msg, host_time)
        except (AttributeError, TypeError, ValueError) as exc:
            return self._skip("garbage", raw, f"unreadable fields: {exc}")
        if fix is None:
            self.counters.no_fix += 1
            return None
        self.counters.fixes += 1
        return fix

    def _skip(self, kind: str, raw: bytes, why: str) -> None:
        setattr(self.counters, kind, getattr(self.counters, kind) + 1)
        text = raw[:60].decode("ascii", "replace")
        self.last_problem = f"{why}: {text!r}"
        return None

    def notes(self) -> list[str]:
        c = self.counters
        line = f"nmea: {c.lines} line(s), {c.fixes} fix(es); {c.ignored} other sentence(s) ignored"
        if c.no_fix:
            line += f"; {c.no_fix} without a valid fix"
        if c.skipped:
            line += f"; skipped {c.bad_checksum} with a bad checksum, {c.garbage} unreadable"
        return [line]


def _fix(msg: object, time_s: float) -> NavFix | None:
    """The :class:`NavFix` of a parsed sentence, or None when it says it has no valid data."""
    kind = msg.msgID  # type: ignore[attr-defined]
    base = {"time_s": float(time_s), "talker": str(msg.talker), "sentence": kind}  # type: ignore[attr-defined]
    get = msg.__dict__.get
    if kind == "GGA":
        lat, lon = _num(get("lat")), _num(get("lon"))
        if _num(get("quality")) == 0 or not (math.isfinite(lat) and math.isfinite(lon)):
            return None
        alt, sep = _num(get("alt")), _num(get("sep"))
        height = alt + (sep if math.isfinite(sep) else 0.0)
        return NavFix(**base, utc=_time(get("time")), lat=lat, lon=lon, height=height)
    if kind == "RMC":
        lat, lon = _num(get("lat")), _num(get("lon"))
        if get("status") != "A" or get("posMode") == "N":
            return None
        if not (math.isfinite(lat) and math.isfinite(lon)):
            return None
        return NavFix(**base, utc=_time(get("time")), date=_date(get("date")), lat=lat, lon=lon,
                      sog_kn=_num(get("spd")), cog=_num(get("cog")))  # fmt: skip
    if kind == "VTG":
        sog = _num(get("sogn"))
        if not math.isfinite(sog):  # some units give km/h only
            sog = _num(get("sogk")) / 1.852
        if get("posMode") == "N" or not math.isfinite(sog):
            return None
        return NavFix(**base, sog_kn=sog, cog=_num(get("cogt")))
    if kind == "HDT":
        heading = _num(get("headingT"))
        return None if not math.isfinite(heading) else NavFix(**base, heading_deg=heading % 360.0)
    if kind == "THS":
        heading = _num(get("headt"))
        if get("mi") == "V" or not math.isfinite(heading):
            return None
        return NavFix(**base, heading_deg=heading % 360.0)
    return None


# ---- the track ---------------------------------------------------------------------------
@dataclass(frozen=True)
class NavWindow:
    """The ship over one window [t0, t1] (see :meth:`NavTrack.window`).

    latitude_deg / longitude_deg: mean of the position fixes; sog_kn: mean speed over ground (the
    fixes' own SOG; where none was sent, the speed of the fitted line through the positions);
    heading_deg: circular mean of the true headings (NaN without any); displacement_north_m /
    displacement_east_m: the slope of a least-squares line through the positions, times the
    window's length: the net displacement of a steady transit with the receiver's noise averaged
    away (and the part of an oscillating position a parabolic-weighted window mean keeps, as the
    hull detector's rates); duration_s: t1 - t0; fixes: position fixes used.
    """

    latitude_deg: float
    longitude_deg: float
    height_m: float
    sog_kn: float
    heading_deg: float
    displacement_north_m: float
    displacement_east_m: float
    duration_s: float
    fixes: int

    @property
    def displacement_m(self) -> float:
        return math.hypot(self.displacement_north_m, self.displacement_east_m)


#: The track's columns, in the order :meth:`NavTrack.arrays` gives them.
TRACK_COLUMNS = ("time_s", "lat", "lon", "height", "sog_kn", "cog", "heading_deg")


class NavTrack:
    """A time series of fixes: columns :data:`TRACK_COLUMNS` (NaN where a fix lacks a field),
    in the order added (times should not decrease). Thread-safe: a reader thread adds, the
    pipeline reads. ``max_age_s`` drops fixes older than that behind the newest; ``max_rows``
    bounds memory whatever the rate (the oldest go first)."""

    def __init__(self, max_age_s: float | None = None, max_rows: int = 1 << 18) -> None:
        self.max_age_s = max_age_s
        self.max_rows = int(max_rows)
        self._data = np.empty((0, len(TRACK_COLUMNS)))
        self._n = 0
        self._lock = threading.Lock()
        self.total = 0  # fixes ever added

    def __len__(self) -> int:
        return self._n

    def add(self, fixes: Iterable[NavFix]) -> int:
        """Append fixes; returns how many."""
        rows = [(f.time_s, f.lat, f.lon, f.height, f.sog_kn, f.cog, f.heading_deg) for f in fixes]
        if not rows:
            return 0
        new = np.array(rows, dtype=float)
        with self._lock:
            need = self._n + len(new)
            if need > len(self._data):
                grown = np.empty((max(need, 2 * len(self._data), 256), len(TRACK_COLUMNS)))
                grown[: self._n] = self._data[: self._n]
                self._data = grown
            self._data[self._n : need] = new
            self._n = need
            self.total += len(new)
            self._trim()
        return len(new)

    def _trim(self) -> None:
        cut = max(0, self._n - self.max_rows)
        if self.max_age_s is not None and self._n:
            newest = self._data[self._n - 1, 0]
            cut = max(cut, int(np.searchsorted(self._data[: self._n, 0], newest - self.max_age_s)))
        if cut and cut >= self._n // 4 or self._n > self.max_rows:  # amortised: move rarely
            self._data[: self._n - cut] = self._data[cut : self._n]
            self._n -= cut

    def arrays(self) -> dict[str, np.ndarray]:
        """A copy of every column."""
        with self._lock:
            data = self._data[: self._n].copy()
        return {name: data[:, j] for j, name in enumerate(TRACK_COLUMNS)}

    def _column(self, name: str) -> np.ndarray:
        return self.arrays()[name]

    time_s = property(lambda self: self._column("time_s"))
    lat = property(lambda self: self._column("lat"))
    lon = property(lambda self: self._column("lon"))
    height = property(lambda self: self._column("height"))
    sog_kn = property(lambda self: self._column("sog_kn"))
    cog = property(lambda self: self._column("cog"))
    heading_deg = property(lambda self: self._column("heading_deg"))

    def latest_position(self) -> tuple[float, float, float, float] | None:
        """(time_s, latitude, longitude, height) of the newest position fix, or None."""
        with self._lock:
            data = self._data[: self._n]
            has = np.flatnonzero(np.isfinite(data[:, 1]))
            if not has.size:
                return None
            t, lat, lon, h = data[has[-1], :4]
        return float(t), float(lat), float(lon), float(h)

    def window(self, t0: float, t1: float, max_gap_s: float = MAX_GAP_S) -> NavWindow | None:
        """The ship over [t0, t1] (:class:`NavWindow`), or None when the position fixes do not
        cover it: every instant of it must lie between two fixes at most ``max_gap_s`` apart,
        or within ``max_gap_s`` of the first or last one. The means are over the fixes inside
        the window; a window shorter than the fixes' interval (none inside) takes the fix
        before it and the one after it, and what was sent between them."""
        g = float(max_gap_s)
        if not t1 >= t0:
            return None
        with self._lock:
            data = self._data[: self._n]
            lo = int(np.searchsorted(data[:, 0], t0 - g, side="left"))
            hi = int(np.searchsorted(data[:, 0], t1 + g, side="right"))
            near = data[lo:hi].copy()
        is_pos = np.isfinite(near[:, 1]) & np.isfinite(near[:, 2])
        pt = near[is_pos, 0]
        if not pt.size or pt[0] > t0 + g or pt[-1] < t1 - g:
            return None
        # the gaps between consecutive fixes that overlap the window
        overlap = (pt[1:] >= t0) & (pt[:-1] <= t1)
        if np.any(np.diff(pt)[overlap] > g):
            return None
        inside = (near[:, 0] >= t0) & (near[:, 0] <= t1)
        if (inside & is_pos).any():
            rows = near[inside]
        else:  # between two fixes: those two, and what came between them
            k = np.flatnonzero(is_pos)
            first = k[near[k, 0] < t0][-1:] if np.any(near[k, 0] < t0) else k[:1]
            last = k[near[k, 0] > t1][:1] if np.any(near[k, 0] > t1) else k[-1:]
            rows = near[int(first[0]) : int(last[0]) + 1]
        pos = rows[np.isfinite(rows[:, 1]) & np.isfinite(rows[:, 2])]
        t, lat, lon = pos[:, 0], pos[:, 1], pos[:, 2]
        lat0 = float(np.mean(lat))
        dlon = (lon - lon[0] + 180.0) % 360.0 - 180.0  # across the antimeridian
        lon0 = float(((lon[0] + np.mean(dlon)) + 180.0) % 360.0 - 180.0)
        north, east = _local_metres(lat - lat0, dlon - np.mean(dlon), lat0)
        T = float(t1 - t0)
        vn, ve = _slope(t, north), _slope(t, east)
        sog = rows[:, 4][np.isfinite(rows[:, 4])]
        sog_kn = float(np.mean(sog)) if sog.size else math.hypot(vn, ve) / KNOT_M_S
        heading = rows[:, 6][np.isfinite(rows[:, 6])]
        height = pos[:, 3][np.isfinite(pos[:, 3])]
        return NavWindow(
            latitude_deg=lat0,
            longitude_deg=lon0,
            height_m=float(np.mean(height)) if height.size else _NAN,
            sog_kn=sog_kn,
            heading_deg=circular_mean_deg(heading),
            displacement_north_m=vn * T,
            displacement_east_m=ve * T,
            duration_s=T,
            fixes=len(pos),
        )


def heading_at(track: NavTrack, times_s: np.ndarray, max_gap_s: float = MAX_GAP_S) -> np.ndarray:
    """The ship's true heading at ``times_s`` (the track's clock), deg in [0, 360): linear
    between the heading fixes on the unwrapped angle (so 359 to 1 passes through 0), NaN where
    the nearest fix before or after is more than ``max_gap_s`` away (the hull detector then takes
    the window's vertical rate as no measurement, recal.detect.creep)."""
    t = np.asarray(times_s, dtype=float)
    data = track.arrays()
    ok = np.isfinite(data["time_s"]) & np.isfinite(data["heading_deg"])
    th, psi = data["time_s"][ok], data["heading_deg"][ok]
    out = np.full(t.shape, _NAN)
    if not th.size:
        return out
    unwrapped = np.degrees(np.unwrap(np.radians(psi)))
    val = np.interp(t, th, unwrapped) % 360.0
    kb = np.searchsorted(th, t, side="right")  # th[kb - 1] <= t
    ka = np.searchsorted(th, t, side="left")  # th[ka] >= t
    before = np.where(kb > 0, t - th[np.maximum(kb - 1, 0)], np.inf)
    after = np.where(ka < th.size, th[np.minimum(ka, th.size - 1)] - t, np.inf)
    covered = (np.minimum(before, after) <= max_gap_s) & (before + after <= 2 * max_gap_s)
    out[covered] = val[covered]
    return out


def circular_mean_deg(angles_deg: np.ndarray) -> float:
    """The direction of the mean unit vector, [0, 360) deg (359 and 1 average to 0, not 180);
    NaN for none."""
    a = np.radians(np.asarray(angles_deg, dtype=float))
    if not a.size:
        return _NAN
    mean = math.degrees(math.atan2(np.mean(np.sin(a)), np.mean(np.cos(a)))) % 360.0
    return 0.0 if mean == 360.0 else mean  # -1e-15 % 360 is 360.0


def _local_metres(dlat_deg: np.ndarray, dlon_deg: np.ndarray, lat_deg: float):
    """North and east metres of small latitude and longitude differences at ``lat_deg``
    (WGS-84 meridian and prime-vertical radii of curvature)."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    w = math.sqrt(1.0 - WGS84_E2 * s2)
    meridian = WGS84_A_M * (1.0 - WGS84_E2) / w**3
    prime = WGS84_A_M / w
    return (np.radians(dlat_deg) * meridian,
            np.radians(dlon_deg) * prime * math.cos(math.radians(lat_deg)))  # fmt: skip


def _slope(t: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y over t (0 with fewer than two distinct times)."""
    tt = t - t.mean()
    d = float(tt @ tt)
    return float(tt @ (y - y.mean()) / d) if d > 0 else 0.0


# ---- a whole log ------------------------------------------------------------------------
@dataclass(frozen=True)
class NmeaLog:
    """A log read by :func:`read_log`: its ``track`` (times in s from the first sentence),
    the UTC of the first sentence when an RMC dates the log (else None), and the counters."""

    track: NavTrack
    utc_start: dt.datetime | None
    counters: NmeaCounters
    notes: list[str]
    duration_s: float


def read_log(data: bytes, source: str = "<log>") -> NmeaLog:
    """Every fix of a log of NMEA lines as received (no clock of the reader's: a line carries no
    time but what the sentence says).

    Each fix is dated by the UTC time of day its sentence carries (GGA, RMC; unwrapped across
    midnight); a sentence without one (VTG, HDT, THS) takes the time of the last sentence that
    had one (an NMEA talker sends a fix's sentences together), those before the first take the
    first's. Times are in s from the first sentence. A log without any readable sentence, or
    without any UTC time, is a :class:`DriverInputError`.
    """
    parser = NmeaParser(source)
    fixes = parser.feed(data) + parser.flush()
    c = parser.counters
    if not fixes:
        seen = f"{c.lines} line(s)"
        if c.lines:
            seen += (f": {c.bad_checksum} with a bad checksum, {c.garbage} unreadable, "
                     f"{c.ignored} of other kinds, {c.no_fix} without a valid fix")  # fmt: skip
        raise DriverInputError(
            f"NMEA log {source} has no GGA, RMC, VTG, HDT or THS sentence with data ({seen})"
            + (f"; last problem: {parser.last_problem}" if parser.last_problem else "")
        )
    clock = [f.utc for f in fixes]
    if all(u is None for u in clock):
        raise DriverInputError(
            f"NMEA log {source} has no sentence that carries UTC time (GGA or RMC): its other "
            "sentences cannot be placed in time"
        )
    day_s = np.array([_NAN if u is None else _seconds(u) for u in clock])
    # unwrap across midnight: a step back of more than 12 h is the next day
    timed = np.flatnonzero(np.isfinite(day_s))
    steps = np.diff(day_s[timed])
    days = np.concatenate(([0.0], np.cumsum(np.where(steps < -43200.0, 86400.0, 0.0))))
    absolute = np.full(len(fixes), _NAN)
    absolute[timed] = day_s[timed] + days
    # untimed sentences take the last timed time before them (the first's before it)
    index = np.maximum.accumulate(np.where(np.isfinite(absolute), np.arange(len(fixes)), -1))
    index = np.where(index < 0, timed[0], index)
    absolute = absolute[index]
    t = absolute - absolute[timed[0]]
    order = np.argsort(t, kind="stable")  # a talker's sentences may come slightly out of order
    t = t[order] - t[order][0]
    utc_start = None
    dated = next((k for k, f in enumerate(fixes) if f.date is not None and f.utc is not None),
                 None)  # fmt: skip
    if dated is not None:
        f = fixes[dated]
        moment = dt.datetime.combine(f.date, f.utc).replace(tzinfo=dt.UTC)
        utc_start = moment - dt.timedelta(seconds=float(absolute[dated] - absolute[order[0]]))
    track = NavTrack(max_rows=max(len(fixes), 1))
    track.add(_restamp(fixes[k], float(tk)) for k, tk in zip(order, t, strict=True))
    return NmeaLog(track, utc_start, c.copy(), parser.notes(), float(t[-1]))


def _seconds(u: dt.time) -> float:
    return u.hour * 3600.0 + u.minute * 60.0 + u.second + u.microsecond * 1e-6


def _restamp(fix: NavFix, time_s: float) -> NavFix:
    return NavFix(time_s, fix.talker, fix.sentence, fix.utc, fix.date, fix.lat, fix.lon,
                  fix.height, fix.sog_kn, fix.cog, fix.heading_deg)  # fmt: skip


# ---- writing sentences (the simulator's ship) ----------------------------------------------
#: Sentences :func:`epoch_sentences` writes by default, in the order a talker sends them.
EPOCH_SENTENCES = ("GGA", "RMC", "VTG", "HDT")


def epoch_sentences(
    utc: dt.datetime,
    lat: float,
    lon: float,
    height_m: float,
    sog_kn: float,
    cog_deg: float,
    heading_deg: float,
    talker: str = "GP",
    heading_talker: str = "HE",
    sentences: tuple[str, ...] = EPOCH_SENTENCES,
) -> bytes:
    """The NMEA 0183 lines of one fix, CR LF ended, built and check-summed by pynmeagps's own
    message classes: GGA (position, height as altitude with a zero geoid separation, quality 1),
    RMC (status A), VTG, HDT (``heading_talker``, a gyrocompass) or THS. Positions are written
    to 1e-5 minute (2 cm), speed and angles to 0.1 (RMC, VTG) and 0.01 (HDT, THS)."""
    from pynmeagps import GET, NMEAMessage

    utc = utc.astimezone(dt.UTC) if utc.tzinfo is not None else utc
    ns, ew = ("N" if lat >= 0 else "S"), ("E" if lon >= 0 else "W")
    cog = round(cog_deg, 1) % 360.0  # rounded first: 359.96 is written 0.0, not 360.0
    heading = round(heading_deg, 2) % 360.0
    out = []
    for kind in sentences:
        if kind == "GGA":
            msg = NMEAMessage(talker, "GGA", GET, time=utc.time(), lat=lat, NS=ns, lon=lon, EW=ew,
                              quality=1, numSV=12, HDOP=0.8, alt=round(height_m, 2),
                              altUnit="M", sep=0.0, sepUnit="M", diffAge="",
                              diffStation="")  # fmt: skip
        elif kind == "RMC":
            msg = NMEAMessage(talker, "RMC", GET, time=utc.time(), status="A", lat=lat, NS=ns,
                              lon=lon, EW=ew, spd=round(sog_kn, 1), cog=cog,
                              date=utc.date(), mv="", mvEW="", posMode="A")  # fmt: skip
        elif kind == "VTG":
            msg = NMEAMessage(talker, "VTG", GET, cogt=cog, cogtUnit="T", cogm="",
                              cogmUnit="M", sogn=round(sog_kn, 1), sognUnit="N",
                              sogk=round(sog_kn * 1.852, 1), sogkUnit="K",
                              posMode="A")  # fmt: skip
        elif kind == "HDT":
            msg = NMEAMessage(heading_talker, "HDT", GET, headingT=heading,
                              headingTu="T")  # fmt: skip
        elif kind == "THS":
            msg = NMEAMessage(heading_talker, "THS", GET, headt=heading,
                              mi="A")  # fmt: skip
        else:
            raise DriverInputError(
                f"cannot write sentence {kind!r} (known: {', '.join(SENTENCES)})"
            )
        out.append(msg.serialize())
    return b"".join(out)
