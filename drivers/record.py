"""Capture the raw byte stream of a live port to a file, with a side file of chunk host times.

Files are written as ``OUT.partial`` and ``OUT.chunks.csv.partial`` and renamed to their final
names when recording ends normally: at --duration, at --max-bytes, when ``stop_event`` is set,
at the end of a replay:// capture, on Ctrl-C (KeyboardInterrupt: everything received so far is
kept), and when the port fails mid-capture (the data so far is kept, then DriverInputError).
Any other failure leaves only the ``.partial`` files, never a half-written file under the final
name.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import serial

from .capture import SIDE_HEADER, side_path
from .config import DEFAULT_CONFIG, DecoderConfig
from .decoder import StreamDecoder
from .errors import DriverInputError
from .formats import FrameFormat
from .frames import DecoderCounters
from .transport import DEFAULT_BAUD, open_port, read_chunk, read_size_for


@dataclass(frozen=True)
class RecordProgress:
    elapsed_s: float
    bytes: int
    counters: DecoderCounters


@dataclass(frozen=True)
class RecordResult:
    """stopped_by: duration, max_bytes, stop_event, eof, interrupt or disconnect."""

    path: Path
    side_path: Path
    bytes: int
    chunks: int
    elapsed_s: float
    counters: DecoderCounters
    stopped_by: str


def _check_output(out: Path) -> None:
    if out.is_dir():
        raise DriverInputError(f"output {out} is a folder; give a file name")
    if not out.parent.exists():
        raise DriverInputError(f"output folder {out.parent} does not exist")


def record(
    url: str,
    out_path: str | os.PathLike[str],
    duration_s: float | None = None,
    max_bytes: int | None = None,
    stop_event: threading.Event | None = None,
    *,
    baudrate: int = DEFAULT_BAUD,
    fmt: str | FrameFormat = "kvh-a",
    config: DecoderConfig = DEFAULT_CONFIG,
    read_size: int = 4096,
    timeout: float = 0.05,
    progress: Callable[[RecordProgress], None] | None = None,
    progress_interval: float = 1.0,
    latency: float = 0.05,
) -> RecordResult:
    """Record ``url`` to ``out_path`` until a limit, ``stop_event``, end of replay or Ctrl-C.

    The stream is decoded on the fly (``fmt``) only to count frames for progress and the result.
    """
    if duration_s is not None and not duration_s > 0:
        raise DriverInputError(f"duration must be positive, not {duration_s}")
    if max_bytes is not None and max_bytes <= 0:
        raise DriverInputError(f"max bytes must be positive, not {max_bytes}")
    out = Path(out_path)
    _check_output(out)
    side = side_path(out)
    decoder = StreamDecoder(fmt, config)
    # Each read waits for about `latency` s of data (at most `timeout`): one side-file line
    # per read, ~20 a second, not one per handful of bytes.
    byte_rate = config.rate_hz * decoder.format.length
    min_read = read_size_for(byte_rate, latency, read_size)
    pause = time.sleep if stop_event is None else stop_event.wait
    tmp = out.with_name(out.name + ".partial")
    tmp_side = side.with_name(side.name + ".partial")
    for path in (tmp, tmp_side):  # an unwritable output is bad input, found before the port opens
        try:
            with open(path, "wb"):
                pass
        except OSError as exc:
            raise DriverInputError(f"cannot write {path}: {exc.strerror or exc}") from None
    try:
        port = open_port(url, baudrate=baudrate, timeout=timeout)
    except BaseException:
        for path in (tmp, tmp_side):
            path.unlink(missing_ok=True)
        raise
    total = chunks = 0
    stopped_by = ""
    failure: BaseException | None = None
    start = time.monotonic()
    next_report = start + progress_interval
    try:
        with open(tmp, "wb") as fh, open(tmp_side, "w", encoding="utf-8") as sh:
            sh.write(f"# capture of {url} at {baudrate} baud, started {time.time():.3f} (unix)\n")
            sh.write(SIDE_HEADER + "\n")
            try:
                while True:
                    now = time.monotonic()
                    if stop_event is not None and stop_event.is_set():
                        stopped_by = "stop_event"
                    elif duration_s is not None and now - start >= duration_s:
                        stopped_by = "duration"
                    elif max_bytes is not None and total >= max_bytes:
                        stopped_by = "max_bytes"
                    elif getattr(port, "at_eof", False) and not port.in_waiting:
                        stopped_by = "eof"
                    if stopped_by:
                        break
                    want = read_size if max_bytes is None else min(read_size, max_bytes - total)
                    try:
                        data = read_chunk(port, min(min_read, want), want, byte_rate, pause)
                    except (serial.SerialException, OSError) as exc:
                        stopped_by, failure = "disconnect", exc
                        break
                    if data:
                        t = time.monotonic()
                        fh.write(data)
                        sh.write(f"{t:.6f},{total},{len(data)}\n")
                        total += len(data)
                        chunks += 1
                        decoder.feed(data, host_time=t)
                    if progress is not None and time.monotonic() >= next_report:
                        next_report += progress_interval
                        progress(RecordProgress(time.monotonic() - start, total, decoder.counters))
            except KeyboardInterrupt:
                stopped_by = "interrupt"
            decoder.flush()
            for handle in (fh, sh):
                handle.flush()
                os.fsync(handle.fileno())
        os.replace(tmp_side, side)
        os.replace(tmp, out)
    finally:
        try:
            port.close()
        except Exception:  # noqa: BLE001 - closing a broken port
            pass
    if failure is not None:
        raise DriverInputError(
            f"{url} failed after {total} bytes ({failure}); the capture so far is saved in {out}"
        )
    return RecordResult(
        out, side, total, chunks, time.monotonic() - start, decoder.counters.copy(), stopped_by
    )
