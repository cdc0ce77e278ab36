"""Helpers for the drivers tests: synthetic streams and batch comparison."""

from __future__ import annotations

import math

import numpy as np

import drivers
from drivers.frames import COLUMNS, FrameBatch


def make_frames(
    n: int, fmt: str = "kvh-a", seed: int = 0, seq0: int = 0, status: int = 0x77
) -> tuple[bytes, dict[str, np.ndarray]]:
    """n valid frames with random plausible values; returns (bytes, the values used)."""
    rng = np.random.default_rng(seed)
    values = {
        "gyro": rng.normal(0.0, 2e-5, (n, 3)).astype(np.float32).astype(np.float64),
        "accel_g": rng.normal(0.0, 0.6, (n, 3)).astype(np.float32).astype(np.float64),
        "seq": (seq0 + np.arange(n)) % 128,
        "temperature_raw": rng.integers(-40, 85, n).astype(np.float64),
        "status": np.full(n, status),
    }
    if fmt == "kvh-b":
        values["timestamp_us"] = (np.arange(n) * 1000 + 4_294_960_000) % 2**32
    if fmt == "kvh-c":
        values["mag_gauss"] = rng.normal(0.0, 0.5, (n, 3)).astype(np.float32).astype(np.float64)
    return drivers.encode_frames(fmt, **values), values


def stream_decode(
    data: bytes, cuts: list[int], fmt: str = "kvh-a", config=drivers.DEFAULT_CONFIG
) -> tuple[FrameBatch, drivers.DecoderCounters]:
    """Feed ``data`` split at ``cuts`` to a StreamDecoder, then flush."""
    dec = drivers.StreamDecoder(fmt, config)
    bounds = [0, *sorted(c for c in cuts if 0 < c < len(data)), len(data)]
    parts = [
        dec.feed(data[a:b], host_time=math.nan) for a, b in zip(bounds, bounds[1:], strict=False)
    ]
    parts.append(dec.flush(host_time=math.nan))
    assert dec.counters.balanced()
    return FrameBatch.concat(parts), dec.counters


def assert_batches_equal(a: FrameBatch, b: FrameBatch, host_time: bool = False) -> None:
    assert a.format == b.format
    assert len(a) == len(b)
    for name in COLUMNS:
        if name == "host_time_s" and not host_time:
            continue
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        assert x.shape == y.shape, name
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
    assert a.extra.keys() == b.extra.keys()
    for name in a.extra:
        assert np.array_equal(a.extra[name], b.extra[name])
