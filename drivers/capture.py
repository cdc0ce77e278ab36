"""Capture files: the raw byte stream plus a side file of host receive times per chunk.

Side file ``OUT.chunks.csv``: '#' comment lines, then the header
``host_monotonic_s,byte_offset,nbytes`` and one row per chunk read from the port.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .bulk import decode_bulk_with_offsets
from .config import DEFAULT_CONFIG, DecoderConfig
from .errors import DriverInputError
from .formats import FrameFormat, get_format
from .frames import DecoderCounters, FrameBatch

SIDE_SUFFIX = ".chunks.csv"
SIDE_HEADER = "host_monotonic_s,byte_offset,nbytes"


def side_path(capture: str | os.PathLike[str]) -> Path:
    """Where the side file of ``capture`` lives."""
    p = Path(capture)
    return p.with_name(p.name + SIDE_SUFFIX)


def read_side_file(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """(host_monotonic_s, byte_offset) arrays of a side file."""
    rows = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            line = line.strip()
            if not line or line.startswith("#") or line == SIDE_HEADER:
                continue
            t, off, _ = line.split(",")
            rows.append((float(t), int(off)))
    if not rows:
        return np.empty(0), np.empty(0, dtype=np.int64)
    arr = np.array(rows, dtype=np.float64)
    return arr[:, 0], arr[:, 1].astype(np.int64)


def decode_capture(
    path: str | os.PathLike[str],
    fmt: str | FrameFormat = "kvh-a",
    config: DecoderConfig = DEFAULT_CONFIG,
) -> tuple[FrameBatch, DecoderCounters]:
    """Decode a capture file; with its side file, each frame gets the host time of the chunk
    that held its last byte, and losses of 128 frames or more are counted from those times (as
    the live streaming decoder fed the same reads did)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise DriverInputError(f"capture file {p} does not exist") from None
    except IsADirectoryError:
        raise DriverInputError(f"capture path {p} is a folder, not a file") from None
    side = side_path(p)
    chunks = read_side_file(side) if side.exists() else None
    batch, counters, _ = decode_bulk_with_offsets(data, get_format(fmt), config, chunks)
    return batch, counters
