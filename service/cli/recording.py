"""The recording named by ``recal positions`` / ``noise`` / ``navigate`` arguments.

Reading lives in :mod:`drivers.recording` (any registered input format, streamed in chunks);
this module only turns the parsed command line into the format's options.
"""

from __future__ import annotations

import argparse
from typing import Any

#: Bytes read at a time (drivers.recording.CHUNK_BYTES; tests lower it to exercise chunking).
CHUNK_BYTES = 4 << 20


def open_recording(args: argparse.Namespace) -> Any:
    """A :class:`drivers.recording.Recording` for the arguments; bad input fails here."""
    from drivers.recording import Recording

    fmt, options = format_options(args)
    return Recording(args.inputs, fmt, options, chunk_bytes=CHUNK_BYTES)


def format_options(args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    """(format, its options from the flags given); a flag of another format is an error."""
    from drivers.errors import DriverInputError
    from drivers.registry import get_input_format, input_formats

    fmt = get_input_format(args.format)
    options: dict[str, Any] = {}
    for other in input_formats():
        for opt in other.options:
            value = getattr(args, _dest(opt.flag), None) if opt.flag else None
            if value is None:
                continue
            if opt.name in fmt.option_names:
                options[opt.name] = value
                continue
            if any(o.flag == opt.flag for o in fmt.options):
                continue  # the same flag sets another option of this format
            owners = [f.name for f in input_formats() if opt.name in f.option_names]
            raise DriverInputError(f"{opt.flag} applies to --format {', '.join(owners)} only")
    return fmt, options


def _dest(flag: str) -> str:
    return flag.lstrip("-").replace("-", "_")
