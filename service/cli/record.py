"""``recal record PORT_URL OUT``: capture the raw byte stream of a live port (drivers.record)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from drivers.record import RecordProgress

#: drivers.transport.DEFAULT_BAUD, repeated here so that building the parser imports no drivers
#: (a test checks they match).
DEFAULT_BAUD = 921600


class _RegisteredFrameFormats:
    """The frame formats registered in drivers.formats (the formats drivers.record decodes to
    count frames), looked up each time they are used, not when the parser is built: building
    it imports no drivers, and ``--format`` and its help follow the registry (a plug-in's
    format too) instead of a list written here."""

    @staticmethod
    def names() -> list[str]:
        from drivers.formats import format_names

        return format_names()

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __contains__(self, name: object) -> bool:
        return name in self.names()

    def __repr__(self) -> str:
        return f"<frame formats of drivers.formats: {', '.join(self.names())}>"


#: The --format choices: the registered frame formats (see :class:`_RegisteredFrameFormats`).
FORMATS = _RegisteredFrameFormats()


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "record",
        help="capture raw bytes from a serial port or URL to a file",
        description="Capture the raw byte stream of PORT_URL to OUT, with host receive times "
        "per chunk in OUT.chunks.csv. PORT_URL is a device (/dev/ttyUSB0), or a pyserial URL "
        "(socket://host:port, replay:///path/capture.bin?speed=max). Stops at --duration, "
        "--max-bytes, the end of a replay, or Ctrl-C (which keeps what was recorded).",
    )
    p.add_argument("port_url", metavar="PORT_URL", help="serial device or pyserial URL")
    p.add_argument("out", metavar="OUT", help="capture file to write")
    p.add_argument("--baud", type=int, default=DEFAULT_BAUD, help="baud rate (default %(default)s)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--max-bytes", type=int, metavar="N", help="stop after N bytes")
    p.add_argument(
        "--format",
        default="kvh-a",
        choices=FORMATS,
        metavar="FORMAT",  # the choices are looked up when used, not to build the parser
        help="frame format, used to count frames and check the capture: one of %(choices)s "
        "(default %(default)s)",
    )
    p.set_defaults(func=run)
    return p


def _progress_printer(tty: bool):
    def show(p: RecordProgress) -> None:
        c = p.counters
        line = (
            f"recording {p.elapsed_s:6.1f} s: {p.bytes} bytes, {c.frames} frames, "
            f"{c.crc_failures} CRC failures, {c.sequence_gaps} sequence gaps"
        )
        print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)

    return show


def run(args: argparse.Namespace) -> int:
    from drivers.diagnose import require_frames
    from drivers.errors import DriverInputError
    from drivers.formats import format_names
    from drivers.record import record

    if args.format not in format_names():
        raise DriverInputError(
            f"unknown --format {args.format!r} (known: {', '.join(format_names())})"
        )
    tty = sys.stderr.isatty()
    result = record(
        args.port_url,
        args.out,
        duration_s=args.duration,
        max_bytes=args.max_bytes,
        baudrate=args.baud,
        fmt=args.format,
        progress=_progress_printer(tty),
        progress_interval=0.5 if tty else 5.0,
    )
    if tty:
        print(file=sys.stderr)
    c = result.counters
    how = (
        "stopped by Ctrl-C, capture kept" if result.stopped_by == "interrupt" else result.stopped_by
    )
    print(
        f"recorded {result.bytes} bytes ({c.frames} {args.format} frames, {c.crc_failures} CRC "
        f"failures, {c.sequence_gaps} sequence gaps) in {result.elapsed_s:.1f} s to "
        f"{result.path} ({how}); host times in {result.side_path}",
        file=sys.stderr,
    )
    require_frames(c, args.format, source=f"the capture saved in {result.path}")
    return 0
