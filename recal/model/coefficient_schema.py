"""The coefficients file's ``schema``: checked on every read, older versions migrated.

A file the product writes carries ``"schema": "recal.coefficients/N"`` (docs/files.md). Reading:

- no ``schema``: a hand-written section 5 layout, version 0;
- ``recal.coefficients/N`` with N up to :data:`VERSION`: migrated one step at a time through
  :data:`MIGRATIONS` (``MIGRATIONS[n]`` turns version n into n + 1);
- a newer N, another tool's schema or a malformed one: a one-line :class:`RecalInputError`.

Pure: dictionaries and text in, dictionaries out; opening files is the caller's business.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping
from typing import Any

from recal.errors import RecalInputError

NAME = "recal.coefficients"
#: The version this recal writes and the newest it reads.
VERSION = 1
SCHEMA = f"{NAME}/{VERSION}"
#: t0_c of a file that does not say (docs/reference.md#effects: the project's reference, 25 degC)
DEFAULT_T0_C = 25.0

_SCHEMA_RE = re.compile(r"^recal\.coefficients/(\d+)$")


def schema_version(data: Mapping[str, Any], source: str = "JSON") -> int:
    """The version ``data`` declares: 0 without ``schema``; a newer, foreign or malformed
    schema is an input error that names it."""
    schema = data.get("schema")
    if schema is None:
        return 0
    match = _SCHEMA_RE.match(schema) if isinstance(schema, str) else None
    if match is None:
        raise RecalInputError(
            f"{source}: schema {schema!r} is not a recal coefficients file "
            f"(expected {NAME}/N, N up to {VERSION})"
        )
    version = int(match.group(1))
    if version > VERSION:
        raise RecalInputError(
            f"{source}: schema {schema} is newer than this recal reads (up to /{VERSION}); "
            "upgrade recal"
        )
    if version < 1:  # /0 was never written: version 0 is the file without a schema
        raise RecalInputError(f"{source}: schema {schema} does not exist (versions 1 to {VERSION})")
    return version


def _v0_to_v1(data: dict[str, Any]) -> dict[str, Any]:
    """Hand-written section 5 layout -> /1: the same keys; /1 states t0_c (25 degC when a
    hand-written file leaves it out) and names its schema."""
    data.setdefault("t0_c", DEFAULT_T0_C)
    return data


#: ``MIGRATIONS[n]`` takes a version-n dict (a copy the caller may change) to version n + 1.
MIGRATIONS: dict[int, Callable[[dict[str, Any]], dict[str, Any]]] = {0: _v0_to_v1}


def upgrade(data: Mapping[str, Any], source: str = "JSON") -> dict[str, Any]:
    """``data`` at :data:`VERSION`: schema checked, then migrated step by step (a new dict;
    the input is left alone). Not an object: input error."""
    if not isinstance(data, Mapping):
        raise RecalInputError(f"{source}: expected a JSON object with 'gyro' and/or 'accel'")
    version = schema_version(data, source)
    out = dict(data)
    for step in range(version, VERSION):
        out = MIGRATIONS[step](out)
    out["schema"] = SCHEMA
    return out


def coefficients_block(data: Mapping[str, Any], source: str = "JSON") -> dict[str, Any]:
    """The coefficients object of a coefficients file, or of a ``calibrate --json`` document or
    stored version (``{"coefficients": {...}, "uncertainty": {...}, ...}``), upgraded.

    A document's ``uncertainty`` and ``covariance`` sit beside its coefficients (older stored
    versions have them only there); a coefficients file (schema 1) carries them inside. The
    inside ones win.
    """
    if not isinstance(data, Mapping):
        raise RecalInputError(f"{source}: expected a JSON object")
    inner = data.get("coefficients")
    if isinstance(inner, Mapping) and not {"gyro", "accel"} & set(data):
        block = upgrade(inner, source)
        for key in ("uncertainty", "covariance"):
            if block.get(key) is None and data.get(key) is not None:
                block[key] = data[key]
        return block
    return upgrade(data, source)


def parse_json(text: str, source: str = "JSON") -> Any:
    """JSON text -> object; a syntax error is a one-line input error with its line."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecalInputError(
            f"{source}: not valid JSON ({exc.msg} at line {exc.lineno})"
        ) from None
    except RecursionError:
        raise RecalInputError(f"{source}: JSON nested too deeply") from None
