"""The input formats: one registry, looked up by name (``--format``, ``[device] format``).

An input format is a streaming parser (bytes or whole lines in, :class:`drivers.FrameBatch` out,
no I/O) plus what a user needs to pick and set it: a name, a one-line description, its framing
(``binary`` or ``lines``), its options and the units it gives. The same parser serves a file
read in chunks (:mod:`drivers.recording`) and a live stream (:class:`drivers.FrameReader`).

This module is light on purpose (no numpy): the CLI builds ``--format`` choices and ``--help``
from it at start-up. Parsers are named ``"module:factory"`` and imported on first use, as
python-can names its bus classes; a plug-in may give the factory itself. Adding a format is one
module holding the parser and one :func:`register` call (built-ins: one entry in ``_BUILTIN``).

The parser a factory returns (:class:`StreamParser`) has ``feed(data, host_time)`` and
``flush(host_time)``, both returning a FrameBatch of the samples completed so far, and
``notes()``: what it has read, in plain words. A ``lines`` parser is fed whole lines only (a
block of bytes that ends with ``\\n``); :class:`drivers.lines.LineSplitter` cuts a byte stream
there, carrying a partial line to the next read. A format with ``inputs == 2`` (the Xsens pair)
is fed ``part=0`` and ``part=1`` streams and cannot be served live from one port.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

from .errors import DriverInputError

Framing = Literal["binary", "lines"]


class StreamParser(Protocol):
    """What a format's factory returns (see the module docstring)."""

    def feed(self, data: bytes, host_time: float = ..., part: int = 0) -> Any: ...

    def flush(self, host_time: float = ...) -> Any: ...

    def notes(self) -> list[str]: ...


@dataclass(frozen=True)
class FormatOption:
    """One setting of a format. ``name`` is the factory's keyword and the ``[device]`` key;
    ``flag`` the CLI option of ``recal positions`` (None: not on the command line); ``parse``
    turns the text of a flag into the value; ``default`` None means unset."""

    name: str
    help: str
    parse: Callable[[str], Any] = str
    default: Any = None
    flag: str | None = None


@dataclass(frozen=True)
class InputFormat:
    """One registered input format (see the module docstring).

    parser: ``"module:factory"`` or the factory; called as ``factory(name, source=...,
    **options)`` with the options the user set (unset ones left out). inputs: files a recording
    of this format is made of: 1 (several files are consecutive parts of one stream) or 2 (a
    pair read side by side, as the Xsens acc and gyro files). units: of the gyro and accel
    samples. has_status / has_temperature: whether the samples carry validity flags and a
    temperature (else those columns are all-valid / NaN).
    """

    name: str
    description: str
    framing: Framing
    parser: str | Callable[..., StreamParser]
    options: tuple[FormatOption, ...] = ()
    inputs: int = 1
    units: tuple[str, str] = ("output units", "output units")
    has_status: bool = False
    has_temperature: bool = True
    aliases: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        if self.framing not in ("binary", "lines"):
            raise ValueError(f"{self.name}: framing must be 'binary' or 'lines'")
        if self.inputs not in (1, 2):
            raise ValueError(f"{self.name}: inputs must be 1 or 2")

    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.options)

    def factory(self) -> Callable[..., StreamParser]:
        if callable(self.parser):
            return self.parser
        module, _, attr = self.parser.partition(":")
        return getattr(importlib.import_module(module), attr)

    def make_parser(self, source: str = "<stream>", **options: Any) -> StreamParser:
        """A fresh parser; options this format does not have are a DriverInputError."""
        unknown = sorted(
            k for k, v in options.items() if v is not None and k not in self.option_names
        )
        if unknown:
            known = ", ".join(self.option_names) or "none"
            raise DriverInputError(
                f"format {self.name} has no option {unknown[0]!r} (its options: {known})"
            )
        given = {k: v for k, v in options.items() if v is not None}
        return self.factory()(self.name, source=source, **given)


# ---- the built-in formats -------------------------------------------------------------------
def _float(text: str) -> float:
    return float(text)


_RATE = FormatOption("rate_hz", "sample rate (Hz)", _float, flag="--rate")
_KVH_OPTIONS = (
    FormatOption("rate_hz", "device data rate (Hz, default 1000)", _float, flag="--rate"),
    FormatOption("gyro_output", "delta (default) or rate", flag="--gyro-output"),
    FormatOption("gyro_units", "rad (default) or deg", flag="--gyro-units"),
    FormatOption("temperature_units", "degC (default) or centi", flag="--temp-units"),
)
#: The parser of the KVH frame formats (drivers.kvh): the formats a simulated capture is written in.
KVH_PARSER = "drivers.kvh_stream:kvh_parser"
_KVH = {
    "framing": "binary",
    "parser": KVH_PARSER,
    "options": _KVH_OPTIONS,
    "units": ("deg/h", "g"),
    "has_status": True,
}
_BUILTIN: tuple[InputFormat, ...] = (
    InputFormat("kvh-a", "KVH Format A binary frames (36 bytes)", **_KVH),
    InputFormat("kvh-b", "KVH Format B binary frames (40 bytes, with timestamp)", **_KVH),
    InputFormat("kvh-c", "KVH Format C binary frames (38 bytes, temperature/magnetometer)", **_KVH),
    InputFormat(
        "xsens-text",
        "Xsens text pair: an acc file and a gyro file of 'time x y z' lines (raw counts)",
        "lines",
        "drivers.xsens_text:xsens_parser",
        (
            _RATE,
            FormatOption("gyro_min", "gyro saturation low (counts, default 0)", _float),
            FormatOption("gyro_max", "gyro saturation high (counts, default 65535)", _float),
        ),
        inputs=2,
        units=("counts", "counts"),
        has_temperature=False,
    ),
    InputFormat(
        "csv",
        "CSV log: a header row, then time_s, gyro_x..z, accel_x..z, temperature_c per row",
        "lines",
        "drivers.csv_log:csv_parser",
        (
            FormatOption(
                "columns",
                "the log's own column names, NEW=OLD,... (e.g. accel_x=ax,time_s=t)",
                flag="--columns",
            ),
            FormatOption(
                "rate_hz",
                "sample rate (Hz); without a time_s column time = row / rate",
                _float,
                flag="--rate",
            ),
            FormatOption(
                "header",
                "the header row, for a stream joined after its header went by",
                flag="--header",
            ),
        ),
    ),
)

_REGISTRY: dict[str, InputFormat] = {}


def register(fmt: InputFormat) -> InputFormat:
    """Add a format (and its aliases); a name can be registered only once."""
    for name in (fmt.name, *fmt.aliases):
        existing = _REGISTRY.get(name)
        if existing is not None and existing != fmt:
            raise ValueError(f"input format {name!r} is already registered")
    for name in (fmt.name, *fmt.aliases):
        _REGISTRY[name] = fmt
    return fmt


def unregister(name: str) -> None:
    """Remove a format and its aliases (tests, unloaded plug-ins)."""
    fmt = _REGISTRY.get(name)
    if fmt is not None:
        for key in [k for k, v in _REGISTRY.items() if v is fmt]:
            del _REGISTRY[key]


for _fmt in _BUILTIN:
    register(_fmt)


def input_formats() -> list[InputFormat]:
    """Every registered format once, in registration order."""
    seen: dict[str, InputFormat] = {}
    for fmt in _REGISTRY.values():
        seen.setdefault(fmt.name, fmt)
    return list(seen.values())


def input_format_names() -> list[str]:
    return [f.name for f in input_formats()]


def kvh_format_names() -> list[str]:
    """The registered formats read by the KVH frame parser: those a simulated KVH capture can be
    written in (``recal simulate --capture-format``, ``service.capture_sim``)."""
    return [f.name for f in input_formats() if f.parser == KVH_PARSER]


def get_input_format(name: str | InputFormat) -> InputFormat:
    """The format registered under ``name``; DriverInputError naming the known ones."""
    if isinstance(name, InputFormat):
        return name
    try:
        return _REGISTRY[str(name).strip().lower()]
    except KeyError:
        known = ", ".join(input_format_names())
        raise DriverInputError(f"unknown input format {name!r} (known: {known})") from None


def all_option_names() -> list[str]:
    """Every option any format has, once (the ``[device]`` keys they become)."""
    out: list[str] = []
    for fmt in input_formats():
        out += [o for o in fmt.option_names if o not in out]
    return out


def check_options(name: str, options: Mapping[str, Any]) -> None:
    """DriverInputError when ``options`` sets one that format ``name`` does not have."""
    fmt = get_input_format(name)
    for key, value in options.items():
        if value is not None and key not in fmt.option_names:
            known = ", ".join(fmt.option_names) or "none"
            raise DriverInputError(
                f"{key} does not apply to format {fmt.name} (its options: {known})"
            )


def describe_formats(sep: str = "; ") -> str:
    """Every format as ``name (framing): description``, joined by ``sep`` (--help, docs)."""
    return sep.join(f"{f.name} ({f.framing}): {f.description}" for f in input_formats())


def markdown_table() -> str:
    """The formats as the table in docs/drivers.md (``python -m drivers.registry`` prints it;
    tests/drivers/test_registry.py checks the docs hold it)."""
    lines = ["| name | framing | files | options | description |", "|---|---|---|---|---|"]
    for f in input_formats():
        options = ", ".join(f"`{o}`" for o in f.option_names) or "none"
        files = "2 (acc, gyro)" if f.inputs == 2 else "1 (or consecutive parts)"
        lines.append(f"| `{f.name}` | {f.framing} | {files} | {options} | {f.description} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown_table(), end="")
