"""Byte-level simulated captures: a :class:`recal.sim.session.Session` as the bytes a KVH would send.

The frames are what the device sends with its default settings: delta angle per sample in rad
(float32), accel in g (float32), temperature as an int16 of whole degC (so quantised), status 0x77
and a sequence number 0-127 that wraps. Optional damage makes the capture look like a real serial
line: flipped bits (the CRC then fails), runs of garbage bytes and frames lost entirely (so the
sequence number jumps). :class:`CaptureInfo` lists every damaged or dropped frame, so a test can
check that none of them reaches a window mean.

Frame 0 is never damaged: decoders measure time from the first good frame, and keeping it means
the decoded ``time_s`` equals the session's ``time_s`` frame for frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers import (
    DecoderConfig,
    encode_frames,
    get_format,
    physical_to_raw_gyro,
    physical_to_raw_temperature,
)
from drivers.registry import kvh_format_names
from recal.model.coefficients import CoefficientSet
from recal.sim.session import Session

#: KVH data formats a capture can be written in (the registry's KVH input formats).
CAPTURE_FORMATS = tuple(kvh_format_names())
_STATUS_ALL_VALID = 0x77


@dataclass(frozen=True)
class Damage:
    """What goes wrong on the line.

    bit_flips: frames with one flipped bit each (anywhere in the frame, header and CRC included).
    garbage: runs of random bytes inserted at random byte positions: between two frames, or
        inside one (which corrupts that frame).
    garbage_max_bytes: each run is 1 to this many bytes long.
    drops: frames removed entirely.
    Every damaged frame is a different one, and never frame 0.
    """

    bit_flips: int = 0
    garbage: int = 0
    garbage_max_bytes: int = 48
    drops: int = 0

    def __post_init__(self) -> None:
        for name in ("bit_flips", "garbage", "drops"):
            if getattr(self, name) < 0:
                raise ValueError(f"damage {name} must be >= 0, not {getattr(self, name)}")
        if self.garbage_max_bytes < 1:
            raise ValueError("damage garbage_max_bytes must be at least 1")

    @property
    def frames(self) -> int:
        """Frames this damage touches (each kind picks its own frames)."""
        return self.bit_flips + self.garbage + self.drops


@dataclass(frozen=True, eq=False)
class CaptureInfo:
    """Where a capture was damaged, by session frame index (the session's sample index).

    frames: frames in the session; frame_length: bytes per frame; bytes: capture length.
    dropped: (k,) frames removed. bit_flips: (k, 3) rows of (frame, byte in frame, bit).
    garbage: (k, 3) rows of (frame, offset in frame, length): the run sits just before byte
    ``offset`` of that frame, so offset 0 is between two frames and leaves both intact.
    """

    format: str
    frames: int
    frame_length: int
    bytes: int
    dropped: np.ndarray
    bit_flips: np.ndarray
    garbage: np.ndarray

    @property
    def corrupted(self) -> np.ndarray:
        """Frames whose bytes were altered (a bit flip, or garbage inside), sorted."""
        inside = self.garbage[self.garbage[:, 1] > 0, 0]
        return np.union1d(self.bit_flips[:, 0], inside).astype(np.int64)

    @property
    def missing(self) -> np.ndarray:
        """Frames no decoder can return: corrupted or dropped, sorted."""
        return np.union1d(self.corrupted, self.dropped).astype(np.int64)

    @property
    def header_broken(self) -> np.ndarray:
        """Corrupted frames whose header was hit: the decoder skips them without a CRC check."""
        hit = self.bit_flips[self.bit_flips[:, 1] < 4, 0]
        inside = (self.garbage[:, 1] > 0) & (self.garbage[:, 1] < 4)
        return np.union1d(hit, self.garbage[inside, 0]).astype(np.int64)

    @property
    def expected_crc_failures(self) -> int:
        """CRC failures a decoder reports: corrupted frames with an intact header (random
        garbage could add a false header candidate too, with odds of about 1 in 2^32 per byte)."""
        return int(np.setdiff1d(self.corrupted, self.header_broken).shape[0])

    @property
    def expected_gaps(self) -> int:
        """Sequence gaps a decoder reports: runs of consecutive missing frames (shorter than the
        128-frame sequence period, which holds for a handful of scattered frames)."""
        m = self.missing
        if m.size == 0:
            return 0
        return 1 + int(np.count_nonzero(np.diff(m) > 1))


def session_to_kvh(
    session: Session,
    fmt: str = "kvh-a",
    config: DecoderConfig | None = None,
    damage: Damage | None = None,
    rng: np.random.Generator | int | None = None,
) -> tuple[bytes, CaptureInfo]:
    """Encode every sample of ``session`` as one KVH frame; then apply ``damage``.

    ``config`` is the device's output setting (default: delta angle in rad, whole degC, at the
    session's rate); its rate must be the session's, since a delta angle is rate / data rate.
    The gyro output N_g is taken as deg/h, so the truth should have gyro scale ~1 (see
    :func:`kvh_like_truth`). Delta angle = rate x sample period: exact in the holds, where the
    rate is constant; during a slew the difference from the true integral does not matter.
    """
    if fmt not in CAPTURE_FORMATS:
        raise ValueError(f"capture format must be one of {', '.join(CAPTURE_FORMATS)}, not {fmt!r}")
    config = DecoderConfig(rate_hz=session.rate_hz) if config is None else config
    if config.rate_hz != session.rate_hz:
        raise ValueError(
            f"the decoder config's rate ({config.rate_hz} Hz) is not the session's "
            f"({session.rate_hz} Hz)"
        )
    damage = damage or Damage()
    rng = np.random.default_rng(rng)
    f = get_format(fmt)
    n = len(session)
    data = encode_kvh(session.gyro_out, session.accel_out, session.temperature_c, fmt, config)
    L = f.length
    if damage.frames > n - 1:
        raise ValueError(f"damage touches {damage.frames} frames; the session has {n}")
    picked = rng.choice(np.arange(1, n), size=damage.frames, replace=False)
    flip_at, rest = np.split(picked, [damage.bit_flips])
    garbage_at, drop_at = np.split(rest, [damage.garbage])

    rows = np.frombuffer(data, dtype=np.uint8).reshape(n, L).copy()
    flip_byte = rng.integers(0, L, flip_at.shape[0])
    flip_bit = rng.integers(0, 8, flip_at.shape[0])
    rows[flip_at, flip_byte] ^= (1 << flip_bit).astype(np.uint8)
    kept = np.ones(n, dtype=bool)
    kept[drop_at] = False
    stream = rows[kept].reshape(-1)
    # Garbage: byte position of each run in the stream of kept frames, then one np.insert.
    offset = rng.integers(0, L, garbage_at.shape[0])
    length = rng.integers(1, damage.garbage_max_bytes + 1, garbage_at.shape[0])
    frame_pos = np.cumsum(kept) - 1  # position of each kept frame in the stream
    where = np.repeat(frame_pos[garbage_at] * L + offset, length)
    stream = np.insert(stream, where, rng.integers(0, 256, where.shape[0], dtype=np.uint8))

    info = CaptureInfo(
        format=fmt,
        frames=n,
        frame_length=L,
        bytes=int(stream.shape[0]),
        dropped=np.sort(drop_at),
        bit_flips=_rows(flip_at, flip_byte, flip_bit),
        garbage=_rows(garbage_at, offset, length),
    )
    return stream.tobytes(), info


def encode_kvh(
    gyro_out: np.ndarray,
    accel_out: np.ndarray,
    temperature_c: np.ndarray,
    fmt: str = "kvh-a",
    config: DecoderConfig | None = None,
    first_frame: int = 0,
) -> bytes:
    """Undamaged KVH frames of samples ``first_frame``, ``first_frame + 1``, ... of a recording
    (gyro in deg/h, accel in g, temperature in degC; ``config`` as in :func:`session_to_kvh`,
    default 1000 Hz): a long recording encoded chunk by chunk gives the bytes of the whole one
    (sequence numbers and Format B timestamps run on)."""
    if fmt not in CAPTURE_FORMATS:
        raise ValueError(f"capture format must be one of {', '.join(CAPTURE_FORMATS)}, not {fmt!r}")
    config = DecoderConfig() if config is None else config
    f = get_format(fmt)
    index = first_frame + np.arange(np.shape(gyro_out)[0], dtype=np.int64)
    timestamp = None
    if "timestamp" in f.fields:
        timestamp = np.rint(index * (1e6 / config.rate_hz)).astype(np.int64)
    return encode_frames(
        f,
        gyro=physical_to_raw_gyro(gyro_out, config),
        accel_g=accel_out,
        seq=index,
        temperature_raw=physical_to_raw_temperature(temperature_c, config),
        status=_STATUS_ALL_VALID,
        timestamp_us=timestamp,
    )


def kvh_like_truth(rng: np.random.Generator | int | None = None) -> CoefficientSet:
    """Coefficients for a device that outputs physical units, as a KVH does.

    Scale 1 +- 300 ppm (output deg/h per deg/h, g per g), gyro bias 0.05-0.5 deg/h, accel bias
    1e-4-1e-3 g (random signs, log-uniform), misalignment ~1e-4 rad, K2 ~1e-5 /g. The seed's
    Table 2 (K ~645 counts per deg/h) describes a counting FOG, not a float32 rad output.
    """
    rng = np.random.default_rng(rng)

    def signed(lo: float, hi: float) -> np.ndarray:
        return rng.choice([-1.0, 1.0], 3) * 10 ** rng.uniform(np.log10(lo), np.log10(hi), 3)

    values = {
        "gyro.scale": 1.0 + 300e-6 * rng.uniform(-1.0, 1.0, 3),
        "gyro.bias": signed(0.05, 0.5),
        "gyro.misalignment": 1e-4 * rng.normal(size=6),
        "accel.scale": 1.0 + 300e-6 * rng.uniform(-1.0, 1.0, 3),
        "accel.bias": signed(1e-4, 1e-3),
        "accel.misalignment": 1e-4 * rng.normal(size=6),
        "accel.quadratic": 1e-5 * rng.normal(size=3),
    }
    return CoefficientSet(values, metadata={"source": "kvh_like_truth (simulated)"})


#: 1-sigma of a good prior for a KVH-like unit (issue 25's acceptance: within 100 ppm,
#: 0.01 deg/h and 20 ug), per coefficient name's last part; the bias by sensor.
PRIOR_SIGMA = {"scale": 1e-4, "gyro.bias": 0.01, "accel.bias": 20e-6, "misalignment": 1e-4,
               "quadratic": 1e-5}  # fmt: skip


def prior_near(
    truth: CoefficientSet,
    rng: np.random.Generator | int | None = None,
    sigma: dict[str, float] | None = None,
) -> CoefficientSet:
    """A previous calibration of the unit ``truth`` describes: every coefficient is the truth
    plus a draw from N(0, sigma**2), and carries that sigma as its 1-sigma (``sigma`` by name as
    :data:`PRIOR_SIGMA`). The prior is honest, not flattering: its errors are as large as it
    says, so about 32 % of its coefficients lie beyond 1 sigma of the truth and 0.3 % beyond 3
    sigma. A fit that holds some at this prior is right within the uncertainty it reports in
    that statistical sense, and only a rate of misses well above the Gaussian's is the fit's
    doing. (Before issue 36 the draw was uniform in +-sigma: an RMS error of 0.58 sigma.)"""
    rng = np.random.default_rng(rng)
    sigma = {**PRIOR_SIGMA, **(sigma or {})}
    prior = truth.copy()
    prior.uncertainty = {}
    for name, value in truth.values.items():
        sd = sigma.get(name, sigma.get(name.split(".", 1)[1]))
        if sd is None:
            continue
        v = np.asarray(value, dtype=float)
        prior.values[name] = v + sd * rng.standard_normal(v.shape)
        prior.uncertainty[name] = np.full(v.shape, float(sd))
    prior.metadata = {"source": "prior_near (simulated: the truth plus N(0, its 1-sigma))"}
    return prior


def _rows(*cols: np.ndarray) -> np.ndarray:
    """(k, len(cols)) int64 rows sorted by the first column."""
    out = np.column_stack([np.asarray(c, dtype=np.int64) for c in cols]).reshape(-1, len(cols))
    return out[np.argsort(out[:, 0], kind="stable")]


def ship_nmea(
    spec: Any,
    latitude_deg: float,
    longitude_deg: float = 0.0,
    height_m: float = 0.0,
    seed: int = 0,
    rate_hz: float = 1.0,
    utc_start: Any = None,
) -> bytes:
    """The ship's own sensors over a simulated vessel recording (recal.sim.vessel.ship_track of
    ``spec`` and ``seed``) as NMEA 0183 lines: an epoch of GGA, RMC, VTG and HDT every
    1 / ``rate_hz`` s, the first at the first sample, dated from ``utc_start`` (a UTC datetime;
    default 2026-01-01), written by pynmeagps's message classes (drivers.nmea.epoch_sentences)."""
    import datetime as dt

    from drivers.nmea import epoch_sentences
    from recal.sim.vessel import ship_track

    if utc_start is None:
        utc_start = dt.datetime(2026, 1, 1, tzinfo=dt.UTC)
    times = np.arange(0.0, spec.duration_s, 1.0 / rate_hz)
    tr = ship_track(spec, times, latitude_deg, longitude_deg, height_m, seed)
    cols = [tr[k] for k in ("latitude_deg", "longitude_deg", "height_m", "sog_kn", "cog_deg",
                            "heading_deg")]  # fmt: skip
    out = bytearray()
    for k, t in enumerate(times.tolist()):  # a loop over fixes (1 to 10 a second), not samples
        out += epoch_sentences(utc_start + dt.timedelta(seconds=t), *(float(c[k]) for c in cols))
    return bytes(out)
