"""Helpers shared by the subcommands: reading inputs with clear errors, atomic writes, progress."""

from __future__ import annotations

import contextlib
import json
import os
import stat
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

if TYPE_CHECKING:
    from recal.model.coefficients import CoefficientSet
    from recal.model.positions import Positions
    from recal.model.terms import Term


def _input_error(message: str) -> Exception:
    # imported when raised: drivers.errors (the InputError base) is not needed to build the parser
    from service.cli.errors import CliInputError

    return CliInputError(message)


def open_input(
    path: str | os.PathLike[str], what: str = "file", empty_ok: bool = False
) -> BinaryIO:
    """Open an input file for reading bytes; every way it can fail is a one-line input error
    naming ``what`` and the path: missing, a directory, not permitted, empty (a regular file of
    0 bytes, unless ``empty_ok``), or any other OS error. The caller closes the file."""
    p = Path(path)
    try:
        fh = p.open("rb")
    except FileNotFoundError:
        raise _input_error(f"{what} {p} does not exist") from None
    except IsADirectoryError:
        raise _input_error(f"{what} {p} is a directory, not a file") from None
    except PermissionError:
        raise _input_error(f"{what} {p}: permission denied") from None
    except OSError as exc:
        raise _input_error(f"cannot read {what} {p}: {exc.strerror or exc}") from None
    info = os.fstat(fh.fileno())
    if stat.S_ISDIR(info.st_mode):  # some systems open a directory without complaint
        fh.close()
        raise _input_error(f"{what} {p} is a directory, not a file")
    if stat.S_ISREG(info.st_mode) and info.st_size == 0 and not empty_ok:
        fh.close()
        raise _input_error(f"{what} {p}: the file is empty")
    return fh


def read_bytes(path: str | os.PathLike[str], what: str = "file", empty_ok: bool = False) -> bytes:
    """A file's bytes, opened by :func:`open_input` (same one-line errors)."""
    with open_input(path, what, empty_ok) as fh:
        try:
            return fh.read()
        except OSError as exc:
            raise _input_error(f"cannot read {what} {path}: {exc.strerror or exc}") from None


def read_text(path: str | os.PathLike[str], what: str = "file", empty_ok: bool = False) -> str:
    """A UTF-8 text file's content (a leading byte-order mark dropped); bytes that are not UTF-8
    are an input error that says where."""
    data = read_bytes(path, what, empty_ok)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise _input_error(
            f"{what} {path} is not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line})"
        ) from None


def atomic_write(path: str | os.PathLike[str], content: str | bytes) -> None:
    """Write ``content`` (text as UTF-8, or bytes) to ``path`` via a temporary file in the same
    folder and a rename, so a failure never leaves a half-written file under the final name."""
    with atomic_stream(path) as fh:
        fh.write(content.encode("utf-8") if isinstance(content, str) else content)


@contextlib.contextmanager
def atomic_stream(path: str | os.PathLike[str]) -> Iterator[BinaryIO]:
    """A file written in pieces (a long simulated recording), atomically: the block writes bytes
    to a temporary file in the same folder, renamed to ``path`` when the block ends and removed
    if it raises."""
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise _input_error(f"output folder {folder} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=folder)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a report or CSV is for sharing
        with os.fdopen(fd, "wb") as fh:
            yield fh
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def load_positions(path: str) -> Positions:
    from recal.model.positions import Positions

    return Positions.from_csv_text(read_text(path, "positions file"), source=str(path))


def load_coefficients(path: str, terms: dict[str, Term] | None = None) -> CoefficientSet:
    """A coefficients file (or a ``calibrate --json`` output): opened here, read by
    recal.model.coefficients.read_coefficients (schema checked, older versions migrated)."""
    from recal.model.coefficients import read_coefficients

    return read_coefficients(read_text(path, "coefficients file"), terms, source=str(path))


def load_plugin(path: str) -> list[Term]:
    """A user's Python file defining ``TERMS = [Term, ...]`` (recal.model.plugins.load_plugin_source):
    opened here, a mistake in it is an input error."""
    from recal.model.plugins import load_plugin_source

    p = Path(path)
    if p.suffix != ".py":
        raise _input_error(f"plugin {p} is not a Python file (expected FILE.py)")
    return load_plugin_source(read_text(p, "plugin"), str(p))


def parse_effects(text: str | None) -> list[str]:
    """'+gyro.bias_temperature,+gyro.bias_drift' -> names (the '+' is optional)."""
    if not text:
        return []
    return [e.strip().lstrip("+") for e in text.split(",") if e.strip()]


def progress_bar(total: int, desc: str, unit: str = "run") -> Any:
    """A tqdm bar on stderr, shown only on a terminal; returns an object with update()/close().

    ``unit="B"`` counts bytes (shown as kB, MB, ... per second).
    """
    from tqdm import tqdm

    return tqdm(
        total=total,
        desc=desc,
        file=sys.stderr,
        disable=not sys.stderr.isatty(),
        unit=unit,
        unit_scale=unit == "B",
        unit_divisor=1024 if unit == "B" else 1000,
        leave=False,
    )


def print_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, allow_nan=False, default=_default) + "\n")


def _default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
