"""Xsens text recordings: one file for the accelerometer, one for the gyro.

Each file has one frame per line: time in s, then x, y, z in raw 16-bit counts, separated by
spaces, tabs, commas or semicolons. Leading header lines (anything not numeric) and comment
lines starting with ``#``, ``%`` or ``//`` are skipped. The two files of a pair must hold the
same frames: same count and same times.

Streaming: :class:`XsensTextParser` turns the bytes of one file, fed in pieces of any size, into
rows; :class:`XsensPair` matches the rows of the two files as they come. Neither does file
I/O; :func:`stream_xsens_pair` reads two files in chunks through them, and
:func:`load_xsens_pair` / :func:`read_xsens_pair` do it all at once.
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np

from .errors import DriverInputError

_COMMENTS = ("#", "%", "//")
_MAX_HEADER_LINES = 50
_TIME_TOL_S = 1e-6  # both files come from one logger: their time stamps match to the digit
CHUNK_BYTES = 4 << 20  # bytes read at a time by stream_xsens_pair


class XsensTextParser:
    """One Xsens text file, streamed: ``feed(bytes) -> (k, 4)`` rows of time_s, x, y, z."""

    def __init__(self, source: str = "<text>") -> None:
        self.source = source
        self._carry = b""
        self._line = 0  # file lines consumed
        self._delimiter: str | None = None
        self._in_header = True
        self._width: int | None = None
        self.rows = 0

    def feed(self, data: bytes | bytearray | memoryview) -> np.ndarray:
        """Add bytes; return the rows of the lines they complete, (k, 4)."""
        buf = self._carry + bytes(data) if self._carry else bytes(data)
        cut = buf.rfind(b"\n") + 1
        self._carry = buf[cut:]
        return self._lines(buf[:cut]) if cut else np.empty((0, 4))

    def flush(self) -> np.ndarray:
        """End of file: parse a last line without a newline; a file without data is an error."""
        buf, self._carry = self._carry, b""
        rows = self._lines(buf) if buf.strip() else np.empty((0, 4))
        if self.rows == 0:
            raise DriverInputError(f"{self.source} holds no data rows (expected 'time x y z' rows)")
        return rows

    def _lines(self, raw: bytes) -> np.ndarray:
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DriverInputError(f"{self.source} is not a text file (not UTF-8)") from None
        first = self._line + 1
        self._line += text.count("\n") + (0 if text.endswith("\n") else 1)
        if self._in_header:
            text, first = self._skip_header(text, first)
            if self._in_header:
                return np.empty((0, 4))
        if not text.strip():
            return np.empty((0, 4))
        try:
            data = np.loadtxt(
                io.StringIO(text),
                delimiter=self._delimiter,
                comments=list(_COMMENTS),
                ndmin=2,
                dtype=np.float64,
            )
        except ValueError:
            raise DriverInputError(f"{self.source}: {self._bad_line(text, first)}") from None
        if data.shape[0] and data.shape[1] != 4:
            raise DriverInputError(
                f"{self.source}: rows have {data.shape[1]} columns; expected 4 (time, x, y, z)"
            )
        finite = np.isfinite(data).all(axis=1)
        if not finite.all():
            row = self.rows + int(np.argmax(~finite))
            raise DriverInputError(f"{self.source}: data row {row + 1} has a NaN or infinite value")
        self.rows += data.shape[0]
        self._width = 4
        return data.reshape(-1, 4)

    def _skip_header(self, text: str, first: int) -> tuple[str, int]:
        lines = text.split("\n")
        for i, line in enumerate(lines):
            if _is_data(line):
                self._in_header = False
                sample = line
                self._delimiter = "," if "," in sample else ";" if ";" in sample else None
                return "\n".join(lines[i:]), first + i
            if first + i > _MAX_HEADER_LINES and line.strip():
                raise DriverInputError(
                    f"{self.source}: no numeric line in the first {_MAX_HEADER_LINES} lines; "
                    "expected 'time x y z' rows"
                )
        return "", first

    def _bad_line(self, text: str, first: int) -> str:
        """Where parsing failed, in the file's own line numbers (error path only)."""
        for number, line in enumerate(text.split("\n"), start=first):
            stripped = line.strip()
            if not stripped or stripped.startswith(_COMMENTS):
                continue
            tokens = stripped.replace(",", " ").replace(";", " ").split()
            try:
                [float(tok) for tok in tokens]
            except ValueError:
                return f"line {number} is not numeric: {stripped[:60]!r}"
            if self._width is not None and len(tokens) != self._width:
                return (
                    f"line {number} has {len(tokens)} values, the lines before have {self._width}"
                )
            self._width = len(tokens)
        return "rows are not 'time x y z' numbers"


def _is_data(line: str) -> bool:
    stripped = line.strip()
    if not stripped or stripped.startswith(_COMMENTS):
        return False
    token = stripped.replace(",", " ").replace(";", " ").split()[0]
    try:
        float(token)
    except ValueError:
        return False
    return True


def parse_xsens_text(text: str | bytes, source: str = "<text>") -> np.ndarray:
    """One Xsens text file -> (N, 4) float array: time_s, x, y, z (raw counts)."""
    parser = XsensTextParser(source)
    data = text.encode("utf-8") if isinstance(text, str) else bytes(text)
    return np.concatenate((parser.feed(data), parser.flush()))


class XsensPair:
    """Matches the rows of an acc file and a gyro file as they are parsed.

    ``add("acc" | "gyro", rows)`` queues rows; ``take()`` returns the frames both files have
    delivered so far (time_s, accel_counts, gyro_counts) after checking their times agree;
    ``finish()`` checks that neither file has rows the other lacks. ``behind()`` names the file
    with fewer queued rows: read that one next and the queues stay short.
    """

    def __init__(self, acc_source: str = "acc file", gyro_source: str = "gyro file") -> None:
        self.sources = {"acc": acc_source, "gyro": gyro_source}
        self._queue: dict[str, list[np.ndarray]] = {"acc": [], "gyro": []}
        self._queued = {"acc": 0, "gyro": 0}
        self.rows = {"acc": 0, "gyro": 0}
        self.frames = 0

    def add(self, which: str, rows: np.ndarray) -> None:
        if rows.shape[0]:
            self._queue[which].append(rows)
            self._queued[which] += rows.shape[0]
            self.rows[which] += rows.shape[0]

    def behind(self) -> str:
        return "acc" if self._queued["acc"] <= self._queued["gyro"] else "gyro"

    def take(self) -> dict[str, np.ndarray]:
        k = min(self._queued.values())
        acc, gyro = self._pop("acc", k), self._pop("gyro", k)
        off = np.abs(acc[:, 0] - gyro[:, 0]) > _TIME_TOL_S
        if off.any():
            i = int(np.argmax(off))
            raise DriverInputError(
                f"{self.sources['acc']} and {self.sources['gyro']} disagree on time at row "
                f"{self.frames + i + 1} ({acc[i, 0]!r} s vs {gyro[i, 0]!r} s): they are not one "
                "recording"
            )
        self.frames += k
        return {"time_s": acc[:, 0], "accel_counts": acc[:, 1:4], "gyro_counts": gyro[:, 1:4]}

    def finish(self) -> None:
        if self.rows["acc"] != self.rows["gyro"]:
            raise DriverInputError(
                f"{self.sources['acc']} has {self.rows['acc']} rows but {self.sources['gyro']} "
                f"has {self.rows['gyro']}: they are not one recording"
            )

    def _pop(self, which: str, k: int) -> np.ndarray:
        queue = self._queue[which]
        rows = (
            np.concatenate(queue) if len(queue) > 1 else (queue[0] if queue else np.empty((0, 4)))
        )
        self._queue[which] = [rows[k:]] if rows.shape[0] > k else []
        self._queued[which] -= k
        return rows[:k]


def read_xsens_pair(
    acc_text: str | bytes,
    gyro_text: str | bytes,
    acc_source: str = "acc file",
    gyro_source: str = "gyro file",
) -> dict[str, np.ndarray]:
    """The text of an acc file and a gyro file -> time_s (N,), accel_counts and gyro_counts (N, 3).

    Raises DriverInputError when a file does not parse or the two do not hold the same frames.
    """
    pair = XsensPair(acc_source, gyro_source)
    pair.add("acc", parse_xsens_text(acc_text, acc_source))
    pair.add("gyro", parse_xsens_text(gyro_text, gyro_source))
    pair.finish()
    return pair.take()


def stream_xsens_pair(
    acc_path: str | os.PathLike[str],
    gyro_path: str | os.PathLike[str],
    chunk_bytes: int = CHUNK_BYTES,
    on_bytes=None,
) -> Iterator[dict[str, np.ndarray]]:
    """Read two files in chunks; yield matched frames as read_xsens_pair gives them, in pieces.

    ``on_bytes(n)`` is called with the size of every chunk read (for a progress bar).
    """
    pair = XsensPair(str(acc_path), str(gyro_path))
    files = {"acc": _open(acc_path), "gyro": _open(gyro_path)}
    parsers = {w: XsensTextParser(pair.sources[w]) for w in files}
    done = {"acc": False, "gyro": False}
    try:
        while not all(done.values()):
            which = pair.behind()
            if done[which]:
                which = "gyro" if which == "acc" else "acc"
            data = files[which].read(chunk_bytes)
            if on_bytes is not None and data:
                on_bytes(len(data))
            if data:
                pair.add(which, parsers[which].feed(data))
            else:
                pair.add(which, parsers[which].flush())
                done[which] = True
            frames = pair.take()
            if frames["time_s"].shape[0]:
                yield frames
        pair.finish()
    finally:
        for fh in files.values():
            fh.close()


def _open(path: str | os.PathLike[str]) -> BinaryIO:
    p = Path(path)
    try:
        return open(p, "rb")  # noqa: SIM115 - closed by the caller
    except FileNotFoundError:
        raise DriverInputError(f"input file {p} does not exist") from None
    except IsADirectoryError:
        raise DriverInputError(f"input {p} is a directory, not a file") from None
    except OSError as exc:
        raise DriverInputError(f"cannot read {p}: {exc.strerror or exc}") from None


def load_xsens_pair(
    acc_path: str | os.PathLike[str], gyro_path: str | os.PathLike[str]
) -> dict[str, np.ndarray]:
    """read_xsens_pair on two files."""
    pieces = list(stream_xsens_pair(acc_path, gyro_path))
    if not pieces:
        return {k: np.empty((0,) if k == "time_s" else (0, 3)) for k in _PAIR_KEYS}
    return {k: np.concatenate([p[k] for p in pieces]) for k in _PAIR_KEYS}


_PAIR_KEYS = ("time_s", "accel_counts", "gyro_counts")


# ---- xsens-text as a registered input format (drivers.registry) ----------------------------
#: Gyro output values at which the Xsens unit of the shared recordings saturates (unsigned
#: 16-bit counts); another unit sets its own (gyro_min, gyro_max).
GYRO_LIMITS_COUNTS = (0.0, 65535.0)


class XsensStreamParser:
    """The acc file (part 0) and the gyro file (part 1), whole lines in, matched frames out
    as :class:`drivers.FrameBatch` (raw counts, no temperature; lost frames from time steps).

    ``behind()`` names the part to read next so that neither queue grows.
    """

    triads = ("gyro", "accel")
    has_temperature = False
    byte_rate = None

    def __init__(
        self,
        name: str = "xsens-text",
        source: str | tuple[str, str] = ("acc file", "gyro file"),
        rate_hz: float | None = None,
        gyro_min: float = GYRO_LIMITS_COUNTS[0],
        gyro_max: float = GYRO_LIMITS_COUNTS[1],
    ) -> None:
        from .frames import DecoderCounters
        from .gaps import GapCounter

        acc, gyro = (source, source) if isinstance(source, str) else source
        if not gyro_min < gyro_max:
            raise DriverInputError(
                f"gyro_min ({gyro_min:g}) must be below gyro_max ({gyro_max:g}) counts"
            )
        self.name = name
        self.sources = (acc, gyro)
        self.sample_rate_hz = rate_hz
        self.gyro_limits = (float(gyro_min), float(gyro_max))
        self._pair = XsensPair(acc, gyro)
        self._parsers = (XsensTextParser(acc), XsensTextParser(gyro))
        self._gaps = GapCounter()
        self.counters = DecoderCounters()

    def behind(self) -> int:
        return 0 if self._pair.behind() == "acc" else 1

    def feed(self, data, host_time: float = float("nan"), part: int = 0):
        self.counters.bytes_in += len(data)
        self._pair.add(("acc", "gyro")[part], self._parsers[part].feed(data))
        return self._out(host_time, end=False)

    def flush(self, host_time: float = float("nan")):
        return self._out(host_time, end=True)

    def end_part(self, part: int) -> None:
        """A file has ended: parse its last line; a file without data rows is an error."""
        self._pair.add(("acc", "gyro")[part], self._parsers[part].flush())

    def finish(self) -> None:
        self._pair.finish()

    def notes(self) -> list[str]:
        acc, gyro = self.sources
        return [f"xsens-text: accel {acc}, gyro {gyro} (raw counts)"]

    def _out(self, host_time: float, end: bool):
        from .frames import FrameBatch

        frames = self._pair.take()
        batch = None
        if frames["time_s"].shape[0]:
            batch = FrameBatch.from_samples(
                self.name,
                frames["time_s"],
                frames["gyro_counts"],
                frames["accel_counts"],
                first_seq=self.counters.frames,
                host_time=host_time,
            )
            self.counters.frames += len(batch)
        out = self._gaps.push(batch) if batch is not None else None
        if end and out is None:
            out = self._gaps.drain()
        return out if out is not None else FrameBatch.empty(self.name)


def xsens_parser(name: str, source="<text>", **options) -> XsensStreamParser:
    """The registry's factory (options: rate_hz, gyro_min, gyro_max)."""
    return XsensStreamParser(name, source, **options)
