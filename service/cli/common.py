"""Helpers shared by the subcommands: reading inputs with clear errors, atomic writes, progress."""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from recal.errors import RecalInputError  # a plain exception class: imports nothing

if TYPE_CHECKING:
    from recal.coefficients import CoefficientSet
    from recal.positions import Positions
    from recal.terms import Term


def read_bytes(path: str | os.PathLike[str], what: str = "file") -> bytes:
    """A file's bytes; a missing, unreadable or directory path is a one-line input error."""
    p = Path(path)
    try:
        return p.read_bytes()
    except FileNotFoundError:
        raise RecalInputError(f"{what} {p} does not exist") from None
    except IsADirectoryError:
        raise RecalInputError(f"{what} {p} is a directory") from None
    except OSError as exc:
        raise RecalInputError(f"cannot read {what} {p}: {exc.strerror or exc}") from None


def read_text(path: str | os.PathLike[str], what: str = "file") -> str:
    data = read_bytes(path, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise RecalInputError(f"{what} {path} is not UTF-8 text") from None


def atomic_write(path: str | os.PathLike[str], content: str | bytes) -> None:
    """Write ``content`` (text as UTF-8, or bytes) to ``path`` via a temporary file in the same
    folder and a rename, so a failure never leaves a half-written file under the final name."""
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise RecalInputError(f"output folder {folder} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=folder)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a report or CSV is for sharing
        with os.fdopen(fd, "wb") as fh:
            fh.write(content.encode("utf-8") if isinstance(content, str) else content)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def load_positions(path: str) -> Positions:
    from recal.positions import Positions

    return Positions.from_csv_text(read_text(path, "positions file"), source=str(path))


def load_coefficients(path: str, terms: dict[str, Term] | None = None) -> CoefficientSet:
    from recal.coefficients import CoefficientSet

    text = read_text(path, "coefficients file")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecalInputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    cs = CoefficientSet.from_json_dict(data, terms, source=str(path))
    cs.metadata.setdefault("source", str(path))
    cs.metadata["source"] = str(path)
    return cs


def load_plugin(path: str) -> list[Term]:
    """Import a user's Python file defining ``TERMS = [Term, ...]`` (see recal.plugins); each
    term is checked (recal.plugins.validate_terms), a mistake is an input error."""

    from recal.plugins import validate_terms

    p = Path(path)
    if not p.is_file():
        raise RecalInputError(f"plugin {p} does not exist")
    name = f"recal_plugin_{p.stem}"
    spec = importlib.util.spec_from_file_location(name, p)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    # registered so dataclasses, pickling and the coefficients file can find the term's file
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)  # type: ignore[union-attr]
    except Exception as exc:  # noqa: BLE001 - user code: report, don't crash
        sys.modules.pop(name, None)
        raise RecalInputError(f"plugin {p} failed to load: {type(exc).__name__}: {exc}") from None
    terms = getattr(module, "TERMS", None)
    if not isinstance(terms, (list, tuple)) or not terms:
        raise RecalInputError(f"plugin {p} must define TERMS = [recal.terms.Term, ...]")
    return validate_terms(terms, str(p))


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
