"""Decoded frames as a batch of numpy columns, and the decoder's counters."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

VALID_STATUS = 0x77  # bits 0-2 gyro x/y/z valid, bits 4-6 accel x/y/z valid

# Column name -> (dtype, trailing shape). Every column has the same length N.
COLUMNS: dict[str, tuple[type, tuple[int, ...]]] = {
    "seq": (np.int64, ()),
    "time_s": (np.float64, ()),
    "host_time_s": (np.float64, ()),
    "gyro_dph": (np.float64, (3,)),
    "accel_g": (np.float64, (3,)),
    "temperature_c": (np.float64, ()),
    "mag_gauss": (np.float64, (3,)),
    "status": (np.uint8, ()),
    "valid": (np.bool_, ()),
    "lost_before": (np.int64, ()),
}


@dataclass(eq=False)
class FrameBatch:
    """N decoded frames of one format, as equal-length numpy columns.

    seq: raw sequence number (0-127). time_s: device time in s since the first frame of the
    stream (from the unwrapped timestamp when the format has one, else from the unwrapped
    sequence number and the configured rate, lost frames counted). host_time_s: monotonic host
    receive time of the chunk that completed the frame (NaN when unknown). gyro_dph: rate in
    deg/h. accel_g: g. temperature_c / mag_gauss: NaN where the frame carries none. status: raw
    status byte; valid: (status & 0x77) == 0x77. lost_before: frames lost just before this one
    according to the sequence gap (0 for the first frame). extra: format-specific columns that
    have no common meaning (e.g. the built-in-test payload), empty for the data formats.
    """

    format: str
    seq: np.ndarray
    time_s: np.ndarray
    host_time_s: np.ndarray
    gyro_dph: np.ndarray
    accel_g: np.ndarray
    temperature_c: np.ndarray
    mag_gauss: np.ndarray
    status: np.ndarray
    valid: np.ndarray
    lost_before: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.seq.shape[0])

    @classmethod
    def empty(
        cls, fmt: str, extra: dict[str, tuple[type, tuple[int, ...]]] | None = None
    ) -> FrameBatch:
        """A batch with no frames (columns of length 0 with the right dtypes and shapes)."""
        cols = {name: np.empty((0, *shape), dtype=dt) for name, (dt, shape) in COLUMNS.items()}
        ext = {name: np.empty((0, *shape), dtype=dt) for name, (dt, shape) in (extra or {}).items()}
        return cls(format=fmt, extra=ext, **cols)

    def __getitem__(self, index: slice | np.ndarray) -> FrameBatch:
        """Rows selected by a slice, a boolean mask or an index array."""
        if isinstance(index, int | np.integer):
            index = slice(int(index), int(index) + 1 or None)
        cols = {name: getattr(self, name)[index] for name in COLUMNS}
        ext = {name: col[index] for name, col in self.extra.items()}
        return FrameBatch(format=self.format, extra=ext, **cols)

    @staticmethod
    def concat(batches: Sequence[FrameBatch] | Iterable[FrameBatch]) -> FrameBatch:
        """One batch from several of the same format, in order."""
        batches = list(batches)
        if not batches:
            raise ValueError("concat needs at least one batch (use FrameBatch.empty)")
        fmt = batches[0].format
        if any(b.format != fmt for b in batches):
            raise ValueError("cannot concatenate batches of different formats")
        if len(batches) == 1:
            return batches[0]
        cols = {name: np.concatenate([getattr(b, name) for b in batches]) for name in COLUMNS}
        ext = {name: np.concatenate([b.extra[name] for b in batches]) for name in batches[0].extra}
        return FrameBatch(format=fmt, extra=ext, **cols)

    @classmethod
    def from_samples(
        cls,
        fmt: str,
        time_s: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        temperature_c: np.ndarray | None = None,
        first_seq: int = 0,
        host_time: float = float("nan"),
    ) -> FrameBatch:
        """A batch of samples from a format without frames (text, CSV): seq counts samples
        from ``first_seq``; valid where gyro and accel are finite; no status or magnetometer;
        temperature NaN when not given; lost_before 0 (drivers.gaps fills it)."""
        n = int(time_s.shape[0])
        gyro = np.asarray(gyro, dtype=np.float64)
        accel = np.asarray(accel, dtype=np.float64)
        valid = np.isfinite(gyro).all(axis=1) & np.isfinite(accel).all(axis=1)
        return cls(
            format=fmt,
            seq=np.arange(first_seq, first_seq + n, dtype=np.int64),
            time_s=np.asarray(time_s, dtype=np.float64),
            host_time_s=np.full(n, host_time),
            gyro_dph=gyro,
            accel_g=accel,
            temperature_c=np.full(n, np.nan)
            if temperature_c is None
            else np.asarray(temperature_c, dtype=np.float64),
            mag_gauss=np.full((n, 3), np.nan),
            status=np.where(valid, VALID_STATUS, 0).astype(np.uint8),
            valid=valid,
            lost_before=np.zeros(n, dtype=np.int64),
        )

    def columns(self) -> dict[str, np.ndarray]:
        """The common columns by name (without format and extra)."""
        return {name: getattr(self, name) for name in COLUMNS}


def concat_batches(batches: Iterable[FrameBatch], fmt: str | None = None) -> FrameBatch:
    """Concatenate batches; with no batches, an empty batch of ``fmt``."""
    batches = list(batches)
    if not batches:
        if fmt is None:
            raise ValueError("concat_batches of nothing needs fmt")
        return FrameBatch.empty(fmt)
    return FrameBatch.concat(batches)


@dataclass
class DecoderCounters:
    """What a decoder has seen.

    Accounting identity (checked by ``balanced()``), for every decoder at every moment:

        bytes_in == frames * frame_length + bytes_skipped + bytes_pending

    bytes_in: bytes fed. frames: frames whose header and CRC checked (kept even with invalid
    status). bytes_skipped: bytes not in any decoded frame, which includes the bytes of CRC-failed
    and truncated candidates (except those that turn out to start the next good frame).
    bytes_pending: bytes held back because they may start a frame not yet complete (always less
    than one frame; 0 after flush()). crc_failures: candidates with the header and a full length
    whose CRC (or checksum) failed. truncated: candidates cut off by the end of the stream (or
    by a reconnect). resyncs: maximal runs of skipped bytes, i.e. times the decoder lost frame
    lock and searched for the next header. sequence_gaps: gap events in the sequence number;
    frames_lost: frames missing in those gaps (sum of lost_before): the sequence number gives
    the count modulo 128, and the timestamp (formats that have one) or the host receive times
    (when the reads' times are known) give the whole count across wraps. misaligned: frames
    whose check passed but that were skipped because a valid frame started inside them and no
    header followed them (a frame cut one byte short that borrowed the next frame's first
    byte): the following frame is kept instead. invalid_status: decoded frames with
    (status & 0x77) != 0x77. headers_seen: headers of every registered format found at the
    positions the decoder examined (frame starts and skipped bytes; bytes inside a decoded frame
    are not examined), used to tell a mis-set format.
    """

    frame_length: int = 0
    bytes_in: int = 0
    frames: int = 0
    bytes_skipped: int = 0
    bytes_pending: int = 0
    crc_failures: int = 0
    truncated: int = 0
    resyncs: int = 0
    sequence_gaps: int = 0
    frames_lost: int = 0
    invalid_status: int = 0
    headers_seen: dict[str, int] = field(default_factory=dict)
    misaligned: int = 0

    def balanced(self) -> bool:
        """True when the accounting identity holds."""
        return self.bytes_in == (
            self.frames * self.frame_length + self.bytes_skipped + self.bytes_pending
        )

    def copy(self) -> DecoderCounters:
        return dataclasses.replace(self, headers_seen=dict(self.headers_seen))

    def as_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)

    def summary(self) -> str:
        """One line for messages: the counters a user needs to judge a stream."""
        return (
            f"{self.bytes_in} bytes read, {self.frames} frames, {self.crc_failures} CRC failures, "
            f"{self.truncated} truncated, {self.bytes_skipped} bytes skipped, "
            f"{self.resyncs} resyncs"
        )
