"""Format registry: declarative frame layouts, looked up by name (e.g. ``--format kvh-a``).

A device family is one module that builds ``FrameFormat`` declarations and calls ``register``.
The streaming and bulk decoders and the encoder read only these declarations.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .crc import crc32_mpeg2_rows, frames_crc_ok
from .errors import DriverInputError

# Field roles the decoder knows. Any other field name is passed through to FrameBatch.extra.
ROLES = ("gyro", "accel", "status", "seq", "temperature", "timestamp", "slot")

# Modules that register the built-in formats; imported on first registry lookup.
BUILTIN_MODULES = ("drivers.kvh",)


@dataclass(frozen=True)
class Field:
    """A field at a byte offset: numpy dtype string (big-endian, e.g. '>f4') and element count."""

    offset: int
    dtype: str
    count: int = 1


@dataclass(frozen=True)
class Multiplexed:
    """A slot whose meaning cycles with the sequence number: ``meanings[seq % period]``.

    Meanings are "temperature", "mag_x", "mag_y" or "mag_z".
    """

    period: int
    meanings: tuple[str, ...]


@dataclass(frozen=True)
class Check:
    """A frame check: ``width`` trailing bytes; ``verify(rows)`` -> bool mask over (K, L) rows;
    ``compute(body)`` -> (K, width) uint8 check bytes for (K, L - width) rows."""

    name: str
    width: int
    verify: Callable[[np.ndarray], np.ndarray]
    compute: Callable[[np.ndarray], np.ndarray]


def _crc_compute(body: np.ndarray) -> np.ndarray:
    crc = crc32_mpeg2_rows(body).astype(">u4")
    return crc.view(np.uint8).reshape(-1, 4)


def _sum8_verify(rows: np.ndarray) -> np.ndarray:
    return (rows[:, :-1].sum(axis=1, dtype=np.uint32) & 0xFF) == rows[:, -1]


def _sum8_compute(body: np.ndarray) -> np.ndarray:
    return (body.sum(axis=1, dtype=np.uint32) & 0xFF).astype(np.uint8).reshape(-1, 1)


CHECKS: dict[str, Check] = {
    "crc32-mpeg2": Check("crc32-mpeg2", 4, frames_crc_ok, _crc_compute),
    "sum8": Check("sum8", 1, _sum8_verify, _sum8_compute),
}


@dataclass(frozen=True)
class FrameFormat:
    """One frame format.

    name: registry name ("kvh-a"). label/family: for messages ("Format A", "KVH").
    header: the sync bytes at offset 0. length: whole frame, check included.
    check: key of CHECKS, computed over every byte before it (the header included).
    fields: role or extra name -> Field. Roles: gyro (3, device units as configured), accel
    (3, raw * accel_scale = g), status, seq, temperature (raw, scaled per DecoderConfig),
    timestamp (integer ticks of timestamp_scale_s, wrapping at timestamp_modulus), slot
    (multiplexed per ``mux``).
    """

    name: str
    label: str
    family: str
    header: bytes
    length: int
    check: str
    fields: Mapping[str, Field]
    seq_modulus: int = 128
    timestamp_modulus: int = 2**32
    timestamp_scale_s: float = 1e-6
    accel_scale: float = 1.0
    mag_scale: float = 1.0
    mux: Multiplexed | None = None
    description: str = ""
    aliases: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        if self.check not in CHECKS:
            raise ValueError(f"{self.name}: unknown check {self.check!r}")
        if "slot" in self.fields and self.mux is None:
            raise ValueError(f"{self.name}: a slot field needs a mux declaration")
        if not self.header or self.length < len(self.header) + CHECKS[self.check].width:
            raise ValueError(f"{self.name}: header/length do not fit")

    @cached_property
    def dtype(self) -> np.dtype:
        """Structured dtype over one frame (itemsize = length), for zero-copy field access."""
        names, formats, offsets = [], [], []
        for name, f in self.fields.items():
            names.append(name)
            formats.append((f.dtype, (f.count,)) if f.count > 1 else f.dtype)
            offsets.append(f.offset)
        return np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": self.length}
        )

    @property
    def checker(self) -> Check:
        return CHECKS[self.check]

    @property
    def extra_fields(self) -> tuple[str, ...]:
        return tuple(n for n in self.fields if n not in ROLES)

    @property
    def header_hex(self) -> str:
        return " ".join(f"{b:02X}" for b in self.header)

    def describe(self) -> str:
        """E.g. "KVH Format B (FE 81 FF 56 headers, 40-byte frames)"."""
        return f"{self.family} {self.label} ({self.header_hex} headers, {self.length}-byte frames)"


_REGISTRY: dict[str, FrameFormat] = {}
_builtin_loaded = False


def register(fmt: FrameFormat) -> FrameFormat:
    """Add a format (and its aliases) to the registry; a name can be registered only once."""
    for name in (fmt.name, *fmt.aliases):
        existing = _REGISTRY.get(name)
        if existing is not None and existing != fmt:
            raise ValueError(f"format name {name!r} is already registered")
        _REGISTRY[name] = fmt
    return fmt


def unregister(name: str) -> None:
    """Remove a format and its aliases (for tests and plug-ins that are unloaded)."""
    fmt = _REGISTRY.get(name)
    if fmt is not None:
        for key in [k for k, v in _REGISTRY.items() if v is fmt]:
            del _REGISTRY[key]


def _load_builtin() -> None:
    global _builtin_loaded
    if not _builtin_loaded:
        _builtin_loaded = True
        for module in BUILTIN_MODULES:
            importlib.import_module(module)


def format_names() -> list[str]:
    """Registered format names (not aliases), in registration order."""
    _load_builtin()
    seen: list[str] = []
    for fmt in _REGISTRY.values():
        if fmt.name not in seen:
            seen.append(fmt.name)
    return seen


def all_formats() -> list[FrameFormat]:
    """Every registered format once."""
    _load_builtin()
    return [_REGISTRY[n] for n in format_names()]


def get_format(fmt: str | FrameFormat) -> FrameFormat:
    """The declaration registered under ``fmt`` (a FrameFormat passes through)."""
    if isinstance(fmt, FrameFormat):
        return fmt
    _load_builtin()
    try:
        return _REGISTRY[str(fmt).strip().lower()]
    except KeyError:
        known = ", ".join(format_names())
        raise DriverInputError(f"unknown frame format {fmt!r} (known: {known})") from None
