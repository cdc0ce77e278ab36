"""Build valid frames (check included) from values, vectorised: for tests and simulators."""

from __future__ import annotations

import numpy as np

from .formats import FrameFormat, get_format

_MAG_AXES = {"mag_x": 0, "mag_y": 1, "mag_z": 2}


def _column(value: np.ndarray | float | int | None, n: int, default: float, shape=()) -> np.ndarray:
    if value is None:
        return np.full((n, *shape), default)
    arr = np.asarray(value)
    return np.broadcast_to(arr, (n, *shape)) if arr.ndim < 1 + len(shape) else arr


def encode_frames(
    fmt: str | FrameFormat,
    gyro: np.ndarray | None = None,
    accel_g: np.ndarray | None = None,
    seq: np.ndarray | None = None,
    temperature_raw: np.ndarray | None = None,
    status: np.ndarray | int | None = None,
    timestamp_us: np.ndarray | None = None,
    mag_gauss: np.ndarray | None = None,
    n: int | None = None,
    **extra: np.ndarray,
) -> bytes:
    """Frames as the device would send them, concatenated.

    gyro: (N, 3) in the device's raw units as configured (e.g. rad delta angle per sample; see
    drivers.physical_to_raw_gyro). accel_g: (N, 3) g. seq: (N,) taken modulo the format's
    sequence modulus (default 0, 1, 2, ...). temperature_raw: (N,) the raw field (whole degC or
    hundredths, rounded for integer fields; for Format C the float slot when seq % 4 == 0).
    status: (N,) or scalar (default 0x77). timestamp_us: (N,) ticks (default seq-independent
    1000 us steps), wrapped to 32 bits. mag_gauss: (N, 3) for Format C slots with seq % 4 != 0.
    extra: format-specific fields, e.g. bit_data=(N, 6) for kvh-bit. N comes from the first
    array given, or ``n``.
    """
    f = get_format(fmt)
    arrays = [gyro, accel_g, seq, temperature_raw, timestamp_us, mag_gauss, *extra.values()]
    if n is None:
        sized = [np.asarray(a) for a in arrays if a is not None and np.ndim(a) > 0]
        if not sized:
            raise ValueError("encode_frames needs at least one array or n")
        n = int(sized[0].shape[0])
    out = np.zeros(n, dtype=f.dtype)
    fields = f.fields
    seq_col = (
        np.arange(n, dtype=np.int64) if seq is None else np.asarray(seq, dtype=np.int64)
    ) % f.seq_modulus
    if "seq" in fields:
        out["seq"] = seq_col
    if "gyro" in fields:
        out["gyro"] = _column(gyro, n, 0.0, (3,))
    if "accel" in fields:
        out["accel"] = _column(accel_g, n, 0.0, (3,)) / f.accel_scale
    if "status" in fields:
        out["status"] = _column(status, n, 0x77)
    if "temperature" in fields:
        temp = _column(temperature_raw, n, 0.0)
        kind = np.dtype(fields["temperature"].dtype).kind
        out["temperature"] = np.rint(temp) if kind in "iu" else temp
    if "timestamp" in fields:
        ticks = np.arange(n, dtype=np.int64) * 1000 if timestamp_us is None else timestamp_us
        out["timestamp"] = np.asarray(ticks, dtype=np.int64) % f.timestamp_modulus
    if f.mux is not None:
        slot = np.zeros(n)
        which = seq_col % f.mux.period
        temp = _column(temperature_raw, n, 0.0)
        mag = _column(mag_gauss, n, 0.0, (3,)) / f.mag_scale
        for i, meaning in enumerate(f.mux.meanings):
            sel = which == i
            if meaning == "temperature":
                slot[sel] = temp[sel]
            elif meaning in _MAG_AXES:
                slot[sel] = mag[sel, _MAG_AXES[meaning]]
        out["slot"] = slot
    for name, value in extra.items():
        if name not in f.extra_fields:
            raise ValueError(f"{f.name} has no field {name!r}")
        out[name] = value
    rows = out.view(np.uint8).reshape(n, f.length)
    rows[:, : len(f.header)] = np.frombuffer(f.header, dtype=np.uint8)
    width = f.checker.width
    rows[:, f.length - width :] = f.checker.compute(rows[:, : f.length - width])
    return rows.tobytes()


def encode_frame(fmt: str | FrameFormat, **values: object) -> bytes:
    """One frame from scalars/short sequences, e.g. encode_frame("kvh-a", gyro=(0, 0, 1e-5), seq=3)."""
    arrays = {k: (None if v is None else np.asarray(v)[None, ...]) for k, v in values.items()}
    return encode_frames(fmt, n=1, **arrays)  # type: ignore[arg-type]
