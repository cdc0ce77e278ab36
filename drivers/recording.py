"""Recordings on disk read through a registered format's streaming parser, in chunks.

A :class:`Recording` can be read more than once (``recal positions`` reads it up to three
times) and never holds more than one chunk of its input in memory. ``frames(on_bytes)`` yields
dicts with the keyword arguments of ``recal.detect.static_detector.StaticDetector.feed`` (time_s, gyro, accel,
temperature_c, valid, lost_before) and calls ``on_bytes(n)`` for every n bytes read.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from .errors import DriverInputError
from .lines import LineSplitter
from .registry import InputFormat, get_input_format

Frames = dict[str, Any]
OnBytes = Callable[[int], None]

#: Bytes read at a time. 4 MiB of KVH Format A is 116 k frames; decoding it peaks near 40 MB
#: (the decoder's temporaries are about 9x the chunk) and runs at the bulk decoder's speed.
CHUNK_BYTES = 4 << 20
#: Bytes read to find a line format's header before the first pass.
_PROBE_BYTES = 1 << 16


class Recording:
    """One recording: its files, its format and the format's options (see the module doc).

    triads: what the input holds (a missing triad is fed as zeros). sample_rate_hz: the rate
    for the detector (None: from the time column). gyro_limits: gyro values at which the
    output saturates, when the format tells (recal.detect.slew_groups drops a slew that reaches them).
    """

    def __init__(
        self,
        paths: list[str],
        fmt: str | InputFormat,
        options: Mapping[str, Any] | None = None,
        chunk_bytes: int = CHUNK_BYTES,
    ) -> None:
        self.format = get_input_format(fmt)
        self.options = {k: v for k, v in (options or {}).items() if v is not None}
        self.chunk_bytes = chunk_bytes
        n = self.format.inputs
        if n == 2 and len(paths) != 2:
            raise DriverInputError(
                f"{self.format.name} takes two inputs, the acc file and the gyro file; "
                f"got {len(paths)}"
            )
        if n == 1 and self.format.framing == "lines" and len(paths) != 1:
            raise DriverInputError(f"{self.format.name} takes one input file; got {len(paths)}")
        self.paths = list(order_pair(paths)) if n == 2 else list(paths)
        self.total_bytes = sum(_size(p) for p in self.paths)
        self._last = self._parser()  # checks the options before any pass
        self.sample_rate_hz = self._last.sample_rate_hz
        self.gyro_limits = self._last.gyro_limits
        self.triads = self._last.triads or self._probe_triads()

    @property
    def source(self) -> str:
        if len(self.paths) == 1 or self.format.inputs == 2:
            return self.paths[0]
        return f"{self.paths[0]} (+{len(self.paths) - 1} parts)"

    def frames(self, on_bytes: OnBytes | None = None) -> Iterator[Frames]:
        parser = self._last = self._parser()
        reads = self._pair_reads if self.format.inputs == 2 else self._stream_reads
        for batch in reads(parser, on_bytes):
            if len(batch):
                yield self._frames(batch, parser)
        parser.finish()

    def notes(self) -> list[str]:
        """What the last pass read, in plain words."""
        return self._last.notes()

    # ---- internals --------------------------------------------------------------------------
    def _parser(self) -> Any:
        source: Any = tuple(self.paths) if self.format.inputs == 2 else self.source
        return self.format.make_parser(source=source, **self.options)

    def _frames(self, batch: Any, parser: Any) -> Frames:
        return {
            "time_s": batch.time_s,
            "gyro": batch.gyro_dph,
            "accel": batch.accel_g,
            "temperature_c": batch.temperature_c if parser.has_temperature else None,
            "valid": batch.valid if self.format.has_status else None,
            "lost_before": batch.lost_before,
        }

    def _stream_reads(self, parser: Any, on_bytes: OnBytes | None) -> Iterator[Any]:
        """Every file in turn as one stream (KVH parts); lines cut whole for a line format."""
        lines = LineSplitter(max_line=1 << 62) if self.format.framing == "lines" else None
        for path in self.paths:
            for data in read_chunks(path, on_bytes, self.chunk_bytes):
                yield parser.feed(lines.feed(data) if lines else data)
        if lines is not None and lines.pending:
            yield parser.feed(lines.flush())
        yield parser.flush()

    def _pair_reads(self, parser: Any, on_bytes: OnBytes | None) -> Iterator[Any]:
        """Two files side by side, reading the one behind (the queues stay short)."""
        files = [_open(p) for p in self.paths]
        splitters = [LineSplitter(max_line=1 << 62), LineSplitter(max_line=1 << 62)]
        done = [False, False]
        size = max(1, self.chunk_bytes // 2)
        try:
            while not all(done):
                part = parser.behind()
                if done[part]:
                    part = 1 - part
                data = files[part].read(size)
                if data:
                    if on_bytes is not None:
                        on_bytes(len(data))
                    yield parser.feed(splitters[part].feed(data), part=part)
                else:
                    yield parser.feed(splitters[part].flush(), part=part)
                    parser.end_part(part)
                    done[part] = True
            yield parser.flush()
        finally:
            for fh in files:
                fh.close()

    def _probe_triads(self) -> tuple[str, ...]:
        """A line format's header, read from the first chunk: bad columns fail before a pass."""
        parser = self._parser()
        lines = LineSplitter(max_line=1 << 62)
        for data in read_chunks(self.paths[0], None, _PROBE_BYTES):
            parser.feed(lines.feed(data))
            if parser.triads is not None:
                return parser.triads
        parser.feed(lines.flush())
        parser.finish()  # raises: empty, or no data rows
        return parser.triads or ("gyro", "accel")


def order_pair(inputs: list[str]) -> tuple[str, str]:
    """(acc, gyro): by 'acc' / 'gyro' in the file names when that is unambiguous, else as given."""
    names = [Path(p).name.lower() for p in inputs]
    acc = [i for i, name in enumerate(names) if "acc" in name]
    gyro = [i for i, name in enumerate(names) if "gyr" in name]
    if acc in ([1], []) and gyro in ([0], []) and (acc or gyro):
        return inputs[1], inputs[0]
    return inputs[0], inputs[1]


def _size(path: str) -> int:
    p = Path(path)
    try:
        if p.is_dir():
            raise DriverInputError(f"input {p} is a directory, not a file")
        return os.stat(p).st_size
    except FileNotFoundError:
        raise DriverInputError(f"input file {p} does not exist") from None
    except OSError as exc:
        raise DriverInputError(f"cannot read {p}: {exc.strerror or exc}") from None


def _open(path: str) -> Any:
    try:
        return open(path, "rb")  # noqa: SIM115 - closed by the caller
    except OSError as exc:
        raise DriverInputError(f"cannot read {path}: {exc.strerror or exc}") from None


def read_chunks(path: str, on_bytes: OnBytes | None, size: int = CHUNK_BYTES) -> Iterator[bytes]:
    """A file's bytes, ``size`` at a time (closed also when the consumer stops early)."""
    with _open(path) as fh:
        while data := fh.read(size):
            if on_bytes is not None:
                on_bytes(len(data))
            yield data
