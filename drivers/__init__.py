"""Bytes to frames: IMU input formats (one registry, :mod:`drivers.registry`), streaming and
bulk decoders, transports.

Uses only the standard library, numpy and pyserial (and pynmeagps for the ship's NMEA 0183
sentences, :mod:`drivers.nmea`); knows nothing of calibration. The names
below are imported on first use (PEP 562), so ``import drivers.registry`` (the CLI's
``--format`` choices) stays light.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

#: Public name -> the module that defines it.
_EXPORTS = {
    "DEFAULT_CONFIG": "config",
    "DecoderConfig": "config",
    "physical_to_raw_gyro": "config",
    "physical_to_raw_temperature": "config",
    "raw_to_physical_gyro": "config",
    "decode_bulk": "bulk",
    "decode_capture": "capture",
    "crc32_mpeg2": "crc",
    "CsvLayout": "csv_log",
    "CsvLogParser": "csv_log",
    "LogChunk": "csv_log",
    "parse_column_map": "csv_log",
    "StreamDecoder": "decoder",
    "diagnose": "diagnose",
    "require_frames": "diagnose",
    "encode_frame": "encode",
    "encode_frames": "encode",
    "DriverInputError": "errors",
    "FrameFormat": "formats",
    "format_names": "formats",
    "get_format": "formats",
    "register": "formats",
    "DecoderCounters": "frames",
    "FrameBatch": "frames",
    "concat_batches": "frames",
    "LineSplitter": "lines",
    "NavReader": "nav_reader",
    "NavFix": "nmea",
    "NavTrack": "nmea",
    "NmeaParser": "nmea",
    "FrameReader": "reader",
    "ReaderHealth": "reader",
    "RecordResult": "record",
    "record": "record",
    "Recording": "recording",
    "FormatOption": "registry",
    "InputFormat": "registry",
    "get_input_format": "registry",
    "input_format_names": "registry",
    "input_formats": "registry",
    "register_input_format": "registry",
    "open_port": "transport",
    "replay_url": "transport",
}
#: Names whose definition is spelt differently in their module.
_RENAMED = {"register_input_format": "register"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        if name == "kvh":  # the KVH frame declarations, as ``drivers.kvh``
            return importlib.import_module(".kvh", __name__)
        raise AttributeError(f"module 'drivers' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), _RENAMED.get(name, name))
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])


class _Package(types.ModuleType):
    """Keeps ``drivers.diagnose`` and ``drivers.record`` the functions: importing a submodule
    of the same name would otherwise bind the module over them."""

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and _EXPORTS.get(name) == name:
            return  # the submodule stays reachable as sys.modules["drivers.<name>"]
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
