"""Xsens text recordings: one file for the accelerometer, one for the gyro.

Each file has one frame per line: time in s, then x, y, z in raw 16-bit counts, separated by
spaces, tabs, commas or semicolons. Leading header lines (anything not numeric) and comment
lines starting with ``#``, ``%`` or ``//`` are skipped. The two files of a pair must hold the
same frames: same count and same times.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from .errors import DriverInputError

_COMMENTS = ("#", "%", "//")
_MAX_HEADER_LINES = 50
_TIME_TOL_S = 1e-6  # both files come from one logger: their time stamps match to the digit


def parse_xsens_text(text: str | bytes, source: str = "<text>") -> np.ndarray:
    """One Xsens text file -> (N, 4) float array: time_s, x, y, z (raw counts)."""
    if isinstance(text, bytes | bytearray):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError:
            raise DriverInputError(f"{source} is not a text file (not UTF-8)") from None
    lines = text.splitlines()
    first = 0
    while first < len(lines) and not _is_data(lines[first]):
        first += 1
        if first > _MAX_HEADER_LINES:
            raise DriverInputError(
                f"{source}: no numeric line in the first {_MAX_HEADER_LINES} lines; "
                "expected 'time x y z' rows"
            )
    if first == len(lines):
        raise DriverInputError(f"{source} holds no data rows (expected 'time x y z' rows)")
    sample = lines[first]
    delimiter = "," if "," in sample else ";" if ";" in sample else None
    try:
        data = np.loadtxt(
            io.StringIO("\n".join(lines[first:])),
            delimiter=delimiter,
            comments=list(_COMMENTS),
            ndmin=2,
            dtype=np.float64,
        )
    except ValueError:
        raise DriverInputError(f"{source}: {_bad_line(lines, first)}") from None
    if data.shape[1] != 4:
        raise DriverInputError(
            f"{source}: rows have {data.shape[1]} columns; expected 4 (time, x, y, z)"
        )
    if not np.isfinite(data).all():
        row = int(np.argmax(~np.isfinite(data).all(axis=1)))
        raise DriverInputError(f"{source}: data row {row + 1} has a NaN or infinite value")
    return data


def _bad_line(lines: list[str], first: int) -> str:
    """Where parsing failed, in the file's own line numbers (error path only)."""
    width = None
    for number, line in enumerate(lines[first:], start=first + 1):
        stripped = line.strip()
        if not stripped or stripped.startswith(_COMMENTS):
            continue
        tokens = stripped.replace(",", " ").replace(";", " ").split()
        try:
            [float(tok) for tok in tokens]
        except ValueError:
            return f"line {number} is not numeric: {stripped[:60]!r}"
        if width is not None and len(tokens) != width:
            return f"line {number} has {len(tokens)} values, the lines before have {width}"
        width = len(tokens)
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


def read_xsens_pair(
    acc_text: str | bytes,
    gyro_text: str | bytes,
    acc_source: str = "acc file",
    gyro_source: str = "gyro file",
) -> dict[str, np.ndarray]:
    """The text of an acc file and a gyro file -> time_s (N,), accel_counts and gyro_counts (N, 3).

    Raises DriverInputError when a file does not parse or the two do not hold the same frames.
    """
    acc = parse_xsens_text(acc_text, acc_source)
    gyro = parse_xsens_text(gyro_text, gyro_source)
    if acc.shape[0] != gyro.shape[0]:
        raise DriverInputError(
            f"{acc_source} has {acc.shape[0]} rows but {gyro_source} has {gyro.shape[0]}: "
            "they are not one recording"
        )
    off = np.abs(acc[:, 0] - gyro[:, 0]) > _TIME_TOL_S
    if off.any():
        i = int(np.argmax(off))
        raise DriverInputError(
            f"{acc_source} and {gyro_source} disagree on time at row {i + 1} "
            f"({acc[i, 0]!r} s vs {gyro[i, 0]!r} s): they are not one recording"
        )
    return {"time_s": acc[:, 0], "accel_counts": acc[:, 1:4], "gyro_counts": gyro[:, 1:4]}


def load_xsens_pair(
    acc_path: str | os.PathLike[str], gyro_path: str | os.PathLike[str]
) -> dict[str, np.ndarray]:
    """read_xsens_pair on two files."""
    texts = []
    for path in (acc_path, gyro_path):
        p = Path(path)
        try:
            texts.append(p.read_bytes())
        except FileNotFoundError:
            raise DriverInputError(f"input file {p} does not exist") from None
        except IsADirectoryError:
            raise DriverInputError(f"input {p} is a directory, not a file") from None
        except OSError as exc:
            raise DriverInputError(f"cannot read {p}: {exc.strerror or exc}") from None
    return read_xsens_pair(texts[0], texts[1], str(acc_path), str(gyro_path))
