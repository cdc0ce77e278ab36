"""The static detector's noise floor: the moving-variance trace of still data, given or learned
from a recording itself (the median trace of its quietest blocks), and the moving-window length
it is measured over."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recal.detect.frames import SLICE_FRAMES as _SLICE
from recal.detect.frames import frame_arrays
from recal.errors import RecalInputError

#: Time steps the sample rate is derived from (the same for every chunking).
RATE_PROBE = 1024

#: Moving-window length the defaults aim at, in frames: the trace of white noise then spreads
#: about 8 % (sqrt(2 / (3 (W - 1)))), the figure threshold_k is chosen against.
NOMINAL_WINDOW_FRAMES = 100


def default_window_s(rate_hz: float) -> float:
    """Default moving-window length, s: about 100 frames, kept between 0.1 s and 1 s.

    1 s at 100 Hz (W = 101, as imu_tk-like detectors use), 0.1 s at 1 kHz (W = 101): the
    statistic spreads the same at every rate, and at 1 kHz a 1 s hold keeps 0.9 s of quiet frames.
    """
    return min(1.0, max(0.1, NOMINAL_WINDOW_FRAMES / rate_hz))


@dataclass(frozen=True)
class NoiseFloor:
    """The moving-variance trace of still data, learned from a recording.

    accel, gyro: typical trace of the moving covariance (sum of the three per-axis variances) of
        still data over ``window_samples`` frames, (accel input units)^2 and (gyro input units)^2.
    window_samples: the moving-window length W it was measured with, frames.
    source: where it comes from, in plain words.
    """

    accel: float
    gyro: float
    window_samples: int
    source: str

    def thresholds(self, k: float) -> tuple[float, float]:
        """(accel, gyro) thresholds on the moving-variance trace: k times the floor."""
        return k * self.accel, k * self.gyro


#: Share of the blocks taken as the provisional floor: still works with only 1/3 still time
#: (the quantile then sits inside the still blocks) down to about 15 %.
FLOOR_QUANTILE = 0.10
#: Blocks within this factor of the provisional floor (both triads) are the "still" ones whose
#: median is the floor: white noise over ~100 frames spreads about 8 %, so every still block
#: passes, and motion (far louder) does not.
FLOOR_SPREAD = 3.0
MIN_FLOOR_BLOCKS = 10


class NoiseFloorEstimator:
    """Learns the noise floor from a recording fed in chunks, with bounded memory.

    The recording is cut into blocks of W frames (the detector's moving window, aligned on the
    first frame); each block gives the trace of its per-axis variance (ddof 0, valid frames
    only; blocks with fewer than (W + 1) / 2 valid frames are skipped) for the accel and the gyro,
    and its start time: three numbers per block. The floor is then the median trace of the
    still blocks (see :meth:`result`). The smallest nonzero step between consecutive valid
    values of each axis is tracked too: quantised data (raw counts) then never get a floor
    below the quantisation noise, step^2 / 12 per axis.
    """

    def __init__(self, window_s: float | None = None, sample_rate_hz: float | None = None) -> None:
        if window_s is not None and not (math.isfinite(window_s) and window_s > 0):
            raise RecalInputError(f"noise floor window_s must be a positive number, not {window_s}")
        if sample_rate_hz is not None and not (
            math.isfinite(sample_rate_hz) and sample_rate_hz > 0
        ):
            raise RecalInputError(
                f"noise floor sample_rate_hz must be a positive number, not {sample_rate_hz}"
            )
        self._window_s = window_s
        self._rate = sample_rate_hz
        self._W: int | None = None
        self._rows = np.empty((0, 8))  # t, gyro xyz, accel xyz, valid: the undecided frames
        self._blocks: list[np.ndarray] = []  # (k, 3): start time, accel trace, gyro trace
        self._step = np.full(6, np.inf)  # smallest nonzero step per axis
        self._last = np.full(6, np.nan)  # last valid frame's values, for steps across chunks
        self._t0: float | None = None
        self._frames = 0

    @property
    def window_samples(self) -> int | None:
        return self._W

    def feed(self, time_s, gyro, accel, valid=None) -> None:
        """Add frames: time in s (N,), gyro and accel (N, 3), optional valid flags (N,)."""
        t, g, a = frame_arrays(time_s, gyro, accel)
        n = t.shape[0]
        ok = np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1)
        if valid is not None:
            v = np.asarray(valid).reshape(-1)
            if v.shape[0] != n:
                raise RecalInputError(f"valid has {v.shape[0]} values for {n} frames")
            ok &= v.astype(bool)
        if n == 0:
            return
        if self._t0 is None:
            self._t0 = float(t[0])
        self._frames += n
        self._track_steps(np.concatenate((g, a), axis=1)[ok])
        rows = np.column_stack((t, g, a, ok))
        rows[~ok, 1:7] = 0.0  # invalid frames carry no weight and may hold garbage
        self._rows = np.concatenate((self._rows, rows))
        self._take_blocks(final=False)

    def result(self) -> NoiseFloor:
        """The noise floor of the frames fed so far; RecalInputError when there are too few."""
        self._take_blocks(final=True)
        blocks = np.concatenate(self._blocks) if self._blocks else np.zeros((0, 3))
        if self._W is None or blocks.shape[0] < MIN_FLOOR_BLOCKS:
            raise RecalInputError(
                f"too little data to learn the noise floor: {blocks.shape[0]} measurable blocks "
                f"of {self._W or '?'} frames, need {MIN_FLOOR_BLOCKS}; give an initial still "
                "period or both thresholds"
            )
        start, tra, trg = blocks.T
        # Provisional floor: a low quantile, inside the still blocks when at least ~15 % of the
        # recording is still (wherever that is). The floor is the median of the blocks near it.
        qa, qg = np.quantile(tra, FLOOR_QUANTILE), np.quantile(trg, FLOOR_QUANTILE)
        # Each triad's floor from its own quiet blocks: a hand's tremor keeps the gyro loud
        # where the accelerometer is still, and must not pick the accelerometer's blocks (the
        # few where both happen to be quietest would give it a floor, and a threshold, too low).
        still_a, still_g = tra <= FLOOR_SPREAD * qa, trg <= FLOOR_SPREAD * qg
        still = still_a | still_g
        quant = self._step**2 / 12.0  # a still quantised signal varies by at least this
        quant[~np.isfinite(quant)] = 0.0
        accel = max(float(np.median(tra[still_a])), float(quant[3:].sum()))
        gyro = max(float(np.median(trg[still_g])), float(quant[:3].sum()))
        rate = self._rate
        span = f"{start[still].min():.0f}-{start[still].max() + self._W / rate:.0f} s"
        counts = (
            f"{int(still_a.sum())}" if (still_a == still_g).all()
            else f"accel {int(still_a.sum())}, gyro {int(still_g.sum())}"
        )  # fmt: skip
        source = (
            f"quietest {self._W / rate:.3g} s stretches of the recording "
            f"({counts} of {blocks.shape[0]}, within {span})"
        )
        return NoiseFloor(accel=accel, gyro=gyro, window_samples=self._W, source=source)

    def _track_steps(self, values: np.ndarray) -> None:
        if values.shape[0] == 0:
            return
        seq = np.concatenate((self._last[None], values))
        step = np.abs(np.diff(seq, axis=0))
        step[~(step > 0)] = np.inf  # zero steps and the NaN before the first frame
        self._step = np.minimum(self._step, step.min(axis=0))
        self._last = values[-1].copy()

    def _take_blocks(self, final: bool) -> None:
        if self._W is None:
            rows = self._rows
            if self._rate is None:
                if rows.shape[0] < RATE_PROBE + 1 and not (final and rows.shape[0] >= 2):
                    return
                probe = rows[: RATE_PROBE + 1, 0]
                self._rate = 1.0 / float(np.median(np.diff(probe)))
            window_s = default_window_s(self._rate) if self._window_s is None else self._window_s
            self._W = 2 * max(1, round(window_s * self._rate / 2)) + 1  # as the detector's
        W = self._W
        nb = self._rows.shape[0] // W
        if nb == 0:
            return
        blk = self._rows[: nb * W].reshape(nb, W, 8)
        self._rows = self._rows[nb * W :]
        w = blk[:, :, 7]
        cnt = w.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = blk[:, :, 1:7].sum(axis=1) / cnt[:, None]
            dev = (blk[:, :, 1:7] - mean[:, None, :]) * w[:, :, None]
            var = (dev * dev).sum(axis=1) / cnt[:, None]  # two-pass: exact for raw counts
        ok = cnt >= (W + 1) // 2
        t_start = blk[:, 0, 0] - self._t0
        stats = np.column_stack((t_start, var[:, 3:].sum(axis=1), var[:, :3].sum(axis=1)))
        self._blocks.append(stats[ok])


def estimate_noise_floor(
    time_s: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    window_s: float | None = None,
    sample_rate_hz: float | None = None,
) -> NoiseFloor:
    """The noise floor of a whole recording (see :class:`NoiseFloorEstimator`)."""
    est = NoiseFloorEstimator(window_s=window_s, sample_rate_hz=sample_rate_hz)
    for lo in range(0, np.shape(time_s)[0], _SLICE):
        sl = slice(lo, lo + _SLICE)
        est.feed(
            np.asarray(time_s)[sl],
            np.asarray(gyro)[sl],
            np.asarray(accel)[sl],
            None if valid is None else np.asarray(valid)[sl],
        )
    return est.result()
