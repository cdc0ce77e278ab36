"""IMU logs as CSV (docs/reference.md#csv): a header row, then one row per sample.

Columns (any order, extra columns ignored): ``time_s`` (optional when a sample rate is given),
``gyro_x``, ``gyro_y``, ``gyro_z``, ``accel_x``, ``accel_y``, ``accel_z`` (either triad may be
missing) in the sensor's output units, and an optional ``temperature_c``. A file's own names are
mapped onto these with ``{"accel_x": "acc_x", ...}`` (``--columns accel_x=acc_x,...``).

:class:`CsvLogParser` is a streaming parser: ``feed`` it bytes of any size, it returns the rows
those bytes complete as a :class:`LogChunk`; ``flush`` ends the stream. It does no file I/O.
Cells are parsed a block of lines at a time with numpy; a bad cell is reported with its line
number. A NaN gyro or accel cell marks that sample invalid; time must be finite and increase.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .errors import DriverInputError

TIME = "time_s"
GYRO = ("gyro_x", "gyro_y", "gyro_z")
ACCEL = ("accel_x", "accel_y", "accel_z")
TEMPERATURE = "temperature_c"
#: Every column the format knows, in the order they are returned.
COLUMNS = (TIME, *GYRO, *ACCEL, TEMPERATURE)
_DELIMITERS = (",", ";", "\t")
_COMMENT = "#"


def parse_column_map(text: str | None) -> dict[str, str]:
    """``"accel_x=acc_x,gyro_x=gx"`` -> ``{"accel_x": "acc_x", "gyro_x": "gx"}`` (new = old)."""
    mapping: dict[str, str] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        new, sep, old = (s.strip() for s in item.partition("="))
        if not sep or not new or not old:
            raise DriverInputError(f"bad column mapping {item.strip()!r}: expected NEW=OLD")
        if new not in COLUMNS:
            raise DriverInputError(
                f"bad column mapping {item.strip()!r}: {new!r} is not one of {', '.join(COLUMNS)}"
            )
        if new in mapping:
            raise DriverInputError(f"column {new} is mapped twice")
        mapping[new] = old
    return mapping


@dataclass(frozen=True)
class CsvLayout:
    """What the header row says: the delimiter and, per known column, its index in a row."""

    names: tuple[str, ...]
    delimiter: str
    index: dict[str, int]  # known column -> position in the row (present ones only)

    @property
    def has_time(self) -> bool:
        return TIME in self.index

    @property
    def triads(self) -> tuple[str, ...]:
        """The triads the file holds: ("gyro", "accel"), ("gyro",) or ("accel",)."""
        return tuple(s for s, cols in (("gyro", GYRO), ("accel", ACCEL)) if cols[0] in self.index)

    @property
    def has_temperature(self) -> bool:
        return TEMPERATURE in self.index

    def source_of(self, column: str) -> str:
        """The file's own name of a known column."""
        return self.names[self.index[column]]


@dataclass(frozen=True, eq=False)
class LogChunk:
    """Consecutive rows of a log. A triad or temperature the file lacks is None.

    time_s: (N,) s, from the time column or row index / rate. gyro, accel: (N, 3) output units.
    temperature_c: (N,) degC. first_line: the file line number of the first row.
    """

    time_s: np.ndarray
    gyro: np.ndarray | None
    accel: np.ndarray | None
    temperature_c: np.ndarray | None
    first_line: int

    def __len__(self) -> int:
        return int(self.time_s.shape[0])


class CsvLogParser:
    """Streaming CSV log parser: bytes in, :class:`LogChunk` out (see the module docstring).

    columns: the file's own names of known columns (new -> old). rate_hz: sample rate, used for
    time when the file has no time column (time = row index / rate). source: the name used in
    error messages.
    """

    def __init__(
        self,
        columns: Mapping[str, str] | None = None,
        rate_hz: float | None = None,
        source: str = "<csv>",
    ) -> None:
        if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
            raise DriverInputError(f"the sample rate must be a positive number, not {rate_hz}")
        self.source = source
        self.rate_hz = rate_hz
        self._map = dict(columns or {})
        self._carry = b""
        self._line = 0  # file lines consumed so far
        self._rows = 0
        self._t_last = -math.inf
        self._started = False
        self.layout: CsvLayout | None = None

    @property
    def rows(self) -> int:
        """Data rows returned so far."""
        return self._rows

    def feed(self, data: bytes | bytearray | memoryview) -> LogChunk | None:
        """Add bytes; return the rows they complete (None when none is complete yet)."""
        buf = self._carry + bytes(data) if self._carry else bytes(data)
        cut = buf.rfind(b"\n") + 1
        self._carry = buf[cut:]
        return self._lines(buf[:cut]) if cut else None

    def flush(self) -> LogChunk | None:
        """End of the log: parse a last line without a newline; check the header was seen."""
        buf, self._carry = self._carry, b""
        chunk = self._lines(buf) if buf.strip() else None
        if self.layout is None:
            raise DriverInputError(f"{self.source} is empty: expected a header row and data rows")
        if self._rows == 0:
            raise DriverInputError(f"{self.source} has a header but no data rows")
        return chunk

    # ---- internals --------------------------------------------------------------------------
    def _lines(self, raw: bytes) -> LogChunk | None:
        if not self._started:
            self._started = True
            raw = raw.removeprefix(b"\xef\xbb\xbf")  # a UTF-8 byte-order mark
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            bad = self._line + raw[: exc.start].count(b"\n") + 1
            raise DriverInputError(f"{self.source}: line {bad} is not UTF-8 text") from None
        first = self._line + 1
        self._line += text.count("\n") + (0 if text.endswith("\n") else 1)
        if self.layout is None:
            text, first = self._header(text, first)
            if self.layout is None:
                return None
        if not text.strip():
            return None
        return self._parse(text, first)

    def _header(self, text: str, first: int) -> tuple[str, int]:
        """Find the header (first non-blank, non-comment line); return the text after it."""
        lines = text.split("\n")
        for i, line in enumerate(lines):
            stripped = line.strip()
            if stripped and not stripped.startswith(_COMMENT):
                self.layout = self._layout(stripped, first + i)
                return "\n".join(lines[i + 1 :]), first + i + 1
        return "", first

    def _layout(self, header: str, line: int) -> CsvLayout:
        counts = {d: header.count(d) for d in _DELIMITERS}
        delimiter = max(_DELIMITERS, key=lambda d: counts[d]) if any(counts.values()) else ","
        names = tuple(n.strip().strip('"').strip() for n in header.split(delimiter))
        dup = sorted({n for n in names if names.count(n) > 1 and n})
        if dup:
            raise DriverInputError(f"{self.source}: the header names {', '.join(dup)} twice")
        position = {n: i for i, n in enumerate(names)}
        index: dict[str, int] = {}
        for col in COLUMNS:
            name = self._map.get(col, col)
            if name in position:
                index[col] = position[name]
            elif col in self._map:
                raise DriverInputError(
                    f"{self.source}: no column {name!r} (mapped to {col}) in the header on line "
                    f"{line}; the columns are {', '.join(names)}"
                )
        for triad in (GYRO, ACCEL):
            have = [c for c in triad if c in index]
            if have and len(have) < 3:
                missing = [self._map.get(c, c) for c in triad if c not in index]
                raise DriverInputError(
                    f"{self.source}: missing column(s) {', '.join(missing)} ({len(have)} of "
                    f"the 3 {triad[0][:-2]} axes present); the columns are {', '.join(names)}"
                )
        if GYRO[0] not in index and ACCEL[0] not in index:
            raise DriverInputError(
                f"{self.source}: no gyro_x, gyro_y, gyro_z or accel_x, accel_y, accel_z columns "
                f"(the columns are {', '.join(names)}); map yours with --columns "
                "gyro_x=NAME,..."
            )
        if TIME not in index and self.rate_hz is None:
            raise DriverInputError(
                f"{self.source}: no time_s column; give the sample rate (--rate HZ) or map "
                "the time column (--columns time_s=NAME)"
            )
        return CsvLayout(names=names, delimiter=delimiter, index=index)

    def _parse(self, text: str, first: int) -> LogChunk:
        layout = self.layout
        assert layout is not None
        cols = [c for c in COLUMNS if c in layout.index]
        usecols = [layout.index[c] for c in cols]
        try:
            values = np.loadtxt(
                io.StringIO(text),
                delimiter=layout.delimiter,
                usecols=usecols,
                ndmin=2,
                dtype=np.float64,
                comments=_COMMENT,
                quotechar='"',
            )
        except ValueError:
            raise DriverInputError(f"{self.source}: {self._locate(text, first, cols)}") from None
        n = values.shape[0]
        at = {c: values[:, j] for j, c in enumerate(cols)}
        if TIME in at:
            t = at[TIME]
            steps = np.diff(t, prepend=self._t_last)
            bad = ~np.isfinite(t) | (steps <= 0)
            if bad.any():
                raise DriverInputError(f"{self.source}: {self._time_error(text, first, t, bad)}")
        else:
            t = np.arange(self._rows, self._rows + n) / self.rate_hz
        if n:
            self._t_last = float(t[-1])
        self._rows += n
        return LogChunk(
            time_s=np.ascontiguousarray(t),
            gyro=np.column_stack([at[c] for c in GYRO]) if GYRO[0] in at else None,
            accel=np.column_stack([at[c] for c in ACCEL]) if ACCEL[0] in at else None,
            temperature_c=np.ascontiguousarray(at[TEMPERATURE]) if TEMPERATURE in at else None,
            first_line=first,
        )

    def _data_lines(self, text: str, first: int):
        """(file line number, fields) of the data rows of a block (error path only)."""
        for number, line in enumerate(text.split("\n"), start=first):
            stripped = line.split(_COMMENT, 1)[0].strip()
            if stripped:
                yield number, [f.strip().strip('"') for f in stripped.split(self.layout.delimiter)]

    def _locate(self, text: str, first: int, cols: list[str]) -> str:
        """Which line and cell numpy could not read, in plain words."""
        layout = self.layout
        for number, fields in self._data_lines(text, first):
            for col in cols:
                j = layout.index[col]
                name = layout.names[j]
                if j >= len(fields):
                    return (
                        f"line {number} has {len(fields)} fields, so no column {name!r} "
                        f"(the header has {len(layout.names)})"
                    )
                try:
                    float(fields[j])
                except ValueError:
                    cell = fields[j][:40]
                    what = "is empty" if not cell else f"is not a number: {cell!r}"
                    return f"line {number}, column {name!r} {what}"
        return "rows do not parse as numbers"

    def _time_error(self, text: str, first: int, t: np.ndarray, bad: np.ndarray) -> str:
        i = int(np.argmax(bad))
        lines = [number for number, _ in self._data_lines(text, first)]
        number = lines[i] if i < len(lines) else first + i
        name = self.layout.source_of(TIME)
        if not math.isfinite(t[i]):
            return f"line {number}, column {name!r}: time is not a finite number"
        before = float(t[i - 1] if i else self._t_last)
        return (
            f"line {number}, column {name!r}: time {float(t[i])!r} s does not come after "
            f"{before!r} s (time must increase)"
        )


# ---- csv as a registered input format (drivers.registry) -----------------------------------
class CsvStreamParser:
    """A CSV log or line stream: whole lines in, :class:`drivers.FrameBatch` out.

    columns: ``NEW=OLD,...`` (``--columns``). rate_hz: time = row / rate without a time
    column. header: the header row, when the stream's own went by before it was joined (then
    every line fed is data). A missing triad is zeros; a NaN gyro or accel cell marks the
    sample invalid; with a time column, lost samples come from its steps (drivers.gaps).
    """

    def __init__(
        self,
        name: str = "csv",
        source: str = "<csv>",
        columns: str | None = None,
        rate_hz: float | None = None,
        header: str | None = None,
    ) -> None:
        from .frames import DecoderCounters
        from .gaps import GapCounter

        self.name = name
        self.source = source
        self.sample_rate_hz = rate_hz
        self.gyro_limits = None
        self._parser = CsvLogParser(parse_column_map(columns), rate_hz, source)
        if header is not None:
            if not header.strip():
                raise DriverInputError("the csv header is empty: give the column names")
            self._parser.feed(header.strip().encode("utf-8") + b"\n")
        self._gaps = GapCounter()
        self.counters = DecoderCounters()

    @property
    def layout(self) -> CsvLayout | None:
        return self._parser.layout

    @property
    def triads(self) -> tuple[str, ...] | None:
        """The triads the log holds (None until its header is read)."""
        return None if self.layout is None else self.layout.triads

    @property
    def has_temperature(self) -> bool:
        return self.layout is not None and self.layout.has_temperature

    @property
    def byte_rate(self) -> float | None:
        """About 80 bytes a line at the configured rate (paces the reader)."""
        return None if self.sample_rate_hz is None else 80.0 * self.sample_rate_hz

    def feed(self, data, host_time: float = math.nan, part: int = 0):
        self.counters.bytes_in += len(data)
        return self._out(self._parser.feed(data), host_time, end=False)

    def flush(self, host_time: float = math.nan):
        """End of the stream (or a reconnect): the samples held to learn the period."""
        return self._out(None, host_time, end=True)

    def finish(self) -> None:
        """End of a recording: an empty log or one without data rows is an error."""
        self._parser.flush()

    def notes(self) -> list[str]:
        layout = self.layout
        if layout is None:
            return []
        what = " and ".join(layout.triads)
        if len(layout.triads) == 1:
            what += f" only (no {'accel' if layout.triads == ('gyro',) else 'gyro'} columns)"
        time = (
            f"time from column {layout.source_of(TIME)!r}"
            if layout.has_time
            else f"time from --rate {self.sample_rate_hz:g} Hz"
        )
        temp = "temperature" if layout.has_temperature else "no temperature"
        rows = self._parser.rows
        return [f"csv: {rows} rows of {what}, {temp}, {time}; output units as in the file"]

    def _out(self, chunk: LogChunk | None, host_time: float, end: bool):
        from .frames import FrameBatch

        batch = None
        if chunk is not None and len(chunk):
            zeros = np.zeros((len(chunk), 3))
            batch = FrameBatch.from_samples(
                self.name,
                chunk.time_s,
                zeros if chunk.gyro is None else chunk.gyro,
                zeros if chunk.accel is None else chunk.accel,
                chunk.temperature_c,
                first_seq=self.counters.frames,
                host_time=host_time,
            )
            self.counters.frames += len(batch)
        if self.layout is not None and not self.layout.has_time:
            out = batch  # time from the rate: no gaps to find
        else:
            out = self._gaps.push(batch) if batch is not None else None
            if end:
                held = self._gaps.drain()
                out = held if out is None else out
        return out if out is not None else FrameBatch.empty(self.name)


def csv_parser(name: str, source: str = "<csv>", **options) -> CsvStreamParser:
    """The registry's factory (options: columns, rate_hz, header)."""
    return CsvStreamParser(name, source, **options)
