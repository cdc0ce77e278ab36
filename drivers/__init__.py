"""Bytes to frames: IMU serial formats, streaming and bulk decoders, transports.

Uses only the standard library, numpy and pyserial; knows nothing of calibration.
"""

from __future__ import annotations

from . import kvh as kvh  # registers the KVH formats
from .bulk import decode_bulk
from .capture import decode_capture
from .config import (
    DEFAULT_CONFIG,
    DecoderConfig,
    physical_to_raw_gyro,
    physical_to_raw_temperature,
    raw_to_physical_gyro,
)
from .crc import crc32_mpeg2
from .csv_log import CsvLayout, CsvLogParser, LogChunk, parse_column_map
from .decoder import StreamDecoder
from .diagnose import diagnose, require_frames
from .encode import encode_frame, encode_frames
from .errors import DriverInputError
from .formats import FrameFormat, format_names, get_format, register
from .frames import DecoderCounters, FrameBatch, concat_batches
from .reader import FrameReader, ReaderHealth
from .record import RecordResult, record
from .transport import open_port, replay_url  # importing transport registers replay://

__all__ = [
    "DEFAULT_CONFIG",
    "CsvLayout",
    "CsvLogParser",
    "DecoderConfig",
    "DecoderCounters",
    "DriverInputError",
    "FrameBatch",
    "FrameFormat",
    "FrameReader",
    "LogChunk",
    "ReaderHealth",
    "RecordResult",
    "StreamDecoder",
    "concat_batches",
    "crc32_mpeg2",
    "decode_bulk",
    "decode_capture",
    "diagnose",
    "encode_frame",
    "encode_frames",
    "format_names",
    "get_format",
    "open_port",
    "parse_column_map",
    "physical_to_raw_gyro",
    "physical_to_raw_temperature",
    "raw_to_physical_gyro",
    "record",
    "register",
    "replay_url",
    "require_frames",
]
