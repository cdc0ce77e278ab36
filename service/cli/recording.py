"""The inputs of ``recal positions``, streamed: files read in chunks, frames out in pieces.

A :class:`Recording` can be read more than once (the flag-free path reads it twice: once to
learn the noise floor, once to find the windows) and never holds more than one chunk of its
input in memory. ``frames(on_bytes)`` yields dicts with the keyword arguments of
``StaticDetector.feed`` (time_s, gyro, accel, temperature_c, valid, lost_before) and calls
``on_bytes(n)`` for every n bytes read, for a progress bar.

Parsers and decoders live in ``drivers`` (no I/O there); the file reading is here.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from recal.errors import RecalInputError

Frames = dict[str, Any]
OnBytes = Callable[[int], None]

#: Bytes read at a time. 4 MiB of KVH Format A is 116 k frames; decoding it peaks near 40 MB
#: (the decoder's temporaries are about 9x the chunk), and the vectorised decoder already runs
#: at its bulk speed (faster, in fact: the chunk stays in cache).
CHUNK_BYTES = 4 << 20
#: Time steps the gap rule's sample period is taken from (the median step), as the detector
#: derives its rate: the first 1024 steps, the same whatever the chunking.
_PERIOD_PROBE = 1024


class Recording:
    """One recording of ``recal positions`` (see the module docstring)."""

    #: Triads the input holds; a missing one is fed as zeros and left out of the output.
    triads: tuple[str, ...] = ("gyro", "accel")
    #: Sample rate for the detector (None: derived from the time column).
    sample_rate_hz: float | None = None
    #: Gyro output values at which the gyro saturates (low, high), when the format tells; a slew
    #: with a sample there cannot be integrated (recal.slews.SlewCollector).
    gyro_limits: tuple[float, float] | None = None

    def __init__(self, paths: list[str]) -> None:
        self.paths = paths
        self.total_bytes = sum(_size(p) for p in paths)

    def frames(self, on_bytes: OnBytes | None = None) -> Iterator[Frames]:
        raise NotImplementedError

    def notes(self) -> list[str]:
        """What the last complete pass read, in plain words."""
        return []


def open_recording(args: argparse.Namespace) -> Recording:
    """The recording named by ``recal positions`` arguments; missing files fail here."""
    if args.columns is not None and args.format != "csv":
        raise RecalInputError("--columns applies to --format csv only")
    if args.format == "xsens-text":
        return XsensRecording(args.inputs, args.rate)
    if args.format == "csv":
        return CsvRecording(args.inputs, args.columns, args.rate)
    return KvhRecording(args.inputs, args.format, args)


# ---- KVH ------------------------------------------------------------------------------------
class KvhRecording(Recording):
    """Consecutive parts of one KVH capture, decoded as one byte stream by StreamDecoder."""

    def __init__(self, paths: list[str], fmt: str, args: argparse.Namespace) -> None:
        from drivers import DecoderConfig

        super().__init__(paths)
        self.format = fmt
        self.config = DecoderConfig(
            gyro_output=args.gyro_output,
            gyro_units=args.gyro_units,
            temperature_units=args.temp_units,
            **({} if args.rate is None else {"rate_hz": args.rate}),
        )
        self._counters = None

    @property
    def source(self) -> str:
        if len(self.paths) == 1:
            return self.paths[0]
        return f"{self.paths[0]} (+{len(self.paths) - 1} parts)"

    def frames(self, on_bytes: OnBytes | None = None) -> Iterator[Frames]:
        from drivers import StreamDecoder, require_frames

        decoder = StreamDecoder(self.format, self.config)
        for path in self.paths:
            for data in _read_chunks(path, on_bytes):
                batch = decoder.feed(data, host_time=float("nan"))
                if len(batch):
                    yield _kvh_frames(batch)
        batch = decoder.flush(host_time=float("nan"))
        if len(batch):
            yield _kvh_frames(batch)
        self._counters = decoder.counters
        require_frames(decoder.counters, self.format, source=self.source)

    def notes(self) -> list[str]:
        c = self._counters
        if c is None:
            return []
        return [
            f"{self.format}: {c.frames} frames decoded, {c.crc_failures} CRC failures, "
            f"{c.sequence_gaps} sequence gaps ({c.frames_lost} frames lost), "
            f"{c.invalid_status} invalid status; gyro deg/h, accel g"
        ]


def _kvh_frames(batch: Any) -> Frames:
    return {
        "time_s": batch.time_s,
        "gyro": batch.gyro_dph,
        "accel": batch.accel_g,
        "temperature_c": batch.temperature_c,
        "valid": batch.valid,
        "lost_before": batch.lost_before,
    }


# ---- Xsens text pair ------------------------------------------------------------------------
class XsensRecording(Recording):
    """An Xsens acc file and gyro file (raw counts), read in step."""

    gyro_limits = (0.0, 65535.0)  # unsigned 16-bit counts

    def __init__(self, inputs: list[str], rate: float | None) -> None:
        if len(inputs) != 2:
            raise RecalInputError(
                f"xsens-text takes two inputs, the acc file and the gyro file; got {len(inputs)}"
            )
        self.acc_path, self.gyro_path = order_pair(inputs)
        super().__init__([self.acc_path, self.gyro_path])
        self.sample_rate_hz = rate

    def frames(self, on_bytes: OnBytes | None = None) -> Iterator[Frames]:
        from drivers.xsens_text import stream_xsens_pair

        pieces = stream_xsens_pair(self.acc_path, self.gyro_path, CHUNK_BYTES // 2, on_bytes)
        gaps = GapCounter()
        for piece in gaps.hold(pieces):
            yield {
                "time_s": piece["time_s"],
                "gyro": piece["gyro_counts"],
                "accel": piece["accel_counts"],
                "temperature_c": None,
                "valid": None,
                "lost_before": gaps.lost(piece["time_s"]),
            }

    def notes(self) -> list[str]:
        return [f"xsens-text: accel {self.acc_path}, gyro {self.gyro_path} (raw counts)"]


def order_pair(inputs: list[str]) -> tuple[str, str]:
    """(acc, gyro): by 'acc' / 'gyro' in the file names when that is unambiguous, else as given."""
    names = [Path(p).name.lower() for p in inputs]
    acc = [i for i, name in enumerate(names) if "acc" in name]
    gyro = [i for i, name in enumerate(names) if "gyr" in name]
    if acc in ([1], []) and gyro in ([0], []) and (acc or gyro):
        return inputs[1], inputs[0]
    return inputs[0], inputs[1]


# ---- CSV log --------------------------------------------------------------------------------
class CsvRecording(Recording):
    """A CSV log (docs/reference.md#csv) parsed by drivers.csv_log.CsvLogParser."""

    def __init__(self, inputs: list[str], columns: str | None, rate: float | None) -> None:
        from drivers.csv_log import CsvLogParser, parse_column_map

        if len(inputs) != 1:
            raise RecalInputError(f"csv takes one input file; got {len(inputs)}")
        super().__init__(inputs)
        self.path = inputs[0]
        self.sample_rate_hz = rate
        self._map = parse_column_map(columns)
        self._rate = rate
        CsvLogParser(self._map, rate, self.path)  # checks the rate
        self._layout = _csv_layout(self.path, self._map, rate)
        self.triads = self._layout.triads
        self._rows = 0

    def frames(self, on_bytes: OnBytes | None = None) -> Iterator[Frames]:
        from drivers.csv_log import CsvLogParser

        parser = CsvLogParser(self._map, self._rate, self.path)
        gaps = GapCounter()

        def chunks():
            for data in _read_chunks(self.path, on_bytes):
                chunk = parser.feed(data)
                if chunk is not None and len(chunk):
                    yield chunk
            chunk = parser.flush()
            if chunk is not None and len(chunk):
                yield chunk

        for chunk in gaps.hold(chunks(), key=lambda c: c.time_s, join=_join_log_chunks):
            n = len(chunk)
            zeros = np.zeros((n, 3))
            yield {
                "time_s": chunk.time_s,
                "gyro": zeros if chunk.gyro is None else chunk.gyro,
                "accel": zeros if chunk.accel is None else chunk.accel,
                "temperature_c": chunk.temperature_c,
                "valid": None,
                "lost_before": gaps.lost(chunk.time_s) if self._layout.has_time else None,
            }
        self._rows = parser.rows

    def notes(self) -> list[str]:
        layout = self._layout
        what = " and ".join(layout.triads)
        if len(layout.triads) == 1:
            what += f" only (no {'accel' if layout.triads == ('gyro',) else 'gyro'} columns)"
        time = (
            f"time from column {layout.source_of('time_s')!r}"
            if layout.has_time
            else f"time from --rate {self._rate:g} Hz"
        )
        temp = "temperature" if layout.has_temperature else "no temperature"
        return [f"csv: {self._rows} rows of {what}, {temp}, {time}; output units as in the file"]


def _csv_layout(path: str, mapping: dict[str, str], rate: float | None) -> Any:
    """The header of a CSV log, read from its first chunk: bad columns fail before any pass."""
    from drivers.csv_log import CsvLogParser

    parser = CsvLogParser(mapping, rate, path)
    for data in _read_chunks(path, None, 1 << 16):
        parser.feed(data)
        if parser.layout is not None:
            return parser.layout
    parser.flush()  # raises: empty, or no data rows
    return parser.layout


def _join_log_chunks(chunks: list[Any]) -> Any:
    from drivers.csv_log import LogChunk

    def cat(name: str) -> np.ndarray | None:
        parts = [getattr(c, name) for c in chunks]
        return None if parts[0] is None else np.concatenate(parts)

    return LogChunk(
        time_s=cat("time_s"),
        gyro=cat("gyro"),
        accel=cat("accel"),
        temperature_c=cat("temperature_c"),
        first_line=chunks[0].first_line,
    )


# ---- shared ---------------------------------------------------------------------------------
class GapCounter:
    """Lost frames from a time column: a step of about k sample periods means k - 1 were lost.

    The period is the median of the first 1024 time steps (jitter of a fraction of a period
    rounds away); :meth:`hold` holds the first pieces back until it is known.
    """

    def __init__(self) -> None:
        self.period: float | None = None
        self._t_last: float | None = None

    def hold(
        self,
        pieces: Iterator[Any],
        key: Callable[[Any], np.ndarray] = lambda p: p["time_s"],
        join: Callable[[list[Any]], Any] | None = None,
    ) -> Iterator[Any]:
        """Pass the pieces through, the first ones joined until the period is known."""
        join = join or _join_dicts
        held: list[Any] = []
        count = 0
        for piece in pieces:
            if self.period is not None:
                yield piece
                continue
            held.append(piece)
            count += key(piece).shape[0]
            if count > _PERIOD_PROBE:
                yield self._learn(join(held), key)
                held = []
        if held:
            yield self._learn(join(held), key)

    def _learn(self, piece: Any, key: Callable[[Any], np.ndarray]) -> Any:
        t = key(piece)[: _PERIOD_PROBE + 1]
        self.period = float(np.median(np.diff(t))) if t.shape[0] > 1 else 0.0
        return piece

    def lost(self, t: np.ndarray) -> np.ndarray:
        """lost_before for the next times (continuing from the previous call)."""
        lost = np.zeros(t.shape[0], dtype=np.int64)
        if t.shape[0] == 0:
            return lost
        prev = t[0] if self._t_last is None else self._t_last
        self._t_last = float(t[-1])
        period = self.period or 0.0
        if not (np.isfinite(period) and period > 0):
            return lost  # the detector reports times that do not increase
        steps = np.diff(t, prepend=prev)
        with np.errstate(invalid="ignore"):
            k = np.rint(steps / period) - 1
        lost[:] = np.where(np.isfinite(k) & (k > 0), k, 0)
        return lost


def _join_dicts(pieces: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    if len(pieces) == 1:
        return pieces[0]
    return {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0]}


def _size(path: str) -> int:
    p = Path(path)
    try:
        if p.is_dir():
            raise RecalInputError(f"input {p} is a directory, not a file")
        return os.stat(p).st_size
    except FileNotFoundError:
        raise RecalInputError(f"input file {p} does not exist") from None
    except OSError as exc:
        raise RecalInputError(f"cannot read {p}: {exc.strerror or exc}") from None


def _read_chunks(path: str, on_bytes: OnBytes | None, size: int = CHUNK_BYTES) -> Iterator[bytes]:
    """A file's bytes, ``size`` at a time."""
    try:
        fh = open(path, "rb")  # noqa: SIM115 - closed below, also when the consumer stops early
    except OSError as exc:
        raise RecalInputError(f"cannot read {path}: {exc.strerror or exc}") from None
    with fh:
        while data := fh.read(size):
            if on_bytes is not None:
                on_bytes(len(data))
            yield data
