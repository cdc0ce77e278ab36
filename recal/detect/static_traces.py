"""The static detector's moving statistics: its geometry at the sample rate and the moving variance.

The window length, edge trim and frames a window needs follow the sample rate (given, or the
median step of the first frames); each centre frame gets the count of valid frames and the trace
of the moving covariance of each triad over a centred window (``inf`` where too few frames are
valid), from chunk-independent block sums. :class:`MovingTraces` is a part of
:class:`recal.detect.static_detector.StaticDetector` and works on that detector's state (its
buffer, references, report and accel track).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recal.detect.floor import RATE_PROBE
from recal.detect.static_sums import (
    COL_A,
    COL_G,
    COL_T,
    COL_TEMP,
    COL_TRA,
    COL_TRG,
    COL_VALID,
    window_sums,
)

#: Machine epsilon: the rounding taken off the moving variance.
EPS = float(np.finfo(np.float64).eps)


@dataclass(frozen=True)
class Geometry:
    """The detector's frame counts at its sample rate."""

    rate: float
    h: int  # half window; W = 2h + 1
    trim: int
    required: int  # frames a kept window needs
    n_min: int  # valid frames a moving window needs to count as measured

    @property
    def block(self) -> int:
        """Frames per block of the Allan statistics: one moving window."""
        return self.W

    @property
    def W(self) -> int:  # noqa: N802 - the window length is W throughout the docs
        return 2 * self.h + 1


class MovingTraces:
    """The :class:`~recal.detect.static_detector.StaticDetector` methods that set its geometry
    and compute the moving-variance traces of each centre frame."""

    # ---- moving statistics ------------------------------------------------------------------
    def _set_geometry(self, final: bool) -> bool:
        cfg = self.config
        rate = cfg.sample_rate_hz
        if rate is None:
            n = min(self._received, RATE_PROBE + 1)
            if n < RATE_PROBE + 1 and not final:
                return False
            if n < 2:
                return False
            rate = 1.0 / float(np.median(np.diff(self._view(0, n)[:, COL_T])))
        window_s, trim_s, min_s = cfg.durations(rate)
        h = max(1, round(window_s * rate / 2))
        self._geom = Geometry(
            rate=rate,
            h=h,
            trim=max(0, round(trim_s * rate)),
            required=max(2, round(min_s * rate)),
            n_min=h + 1,
        )
        self.report.edge_trim_frames = self._geom.trim
        self.report.required_frames = self._geom.required
        self._qhist = np.zeros(self._geom.trim, dtype=bool)  # frames before the stream
        self.report.sample_rate_hz = rate
        self.report.window_samples = self._geom.W
        return True

    def _moving_stats(self, final: bool):
        """Moving count and variance traces for the next centre frames (None if none)."""
        g = self._geom
        h, W, M = g.h, g.W, self._received
        lo = self._next_center
        hi = M if final else max(M - h, min(h, M))
        if hi <= lo:
            return None
        shared = self._shared.pop(0) if self._shared else None
        if shared is not None and (shared[0] != lo or shared[1].shape[0] != hi - lo):
            raise AssertionError("the accel track fell out of step with its detector")
        n = np.zeros(hi - lo) if shared is None else shared[1]
        tra = np.full(hi - lo, np.inf) if shared is None else shared[2]
        trg = np.full(hi - lo, np.inf) if shared is None else shared[3]
        f_lo, f_hi = max(lo, h), min(hi, M - h)  # centres with a full window
        if f_hi > f_lo and shared is None:
            a_lo, a_hi = f_lo - h, f_hi - h  # window starts
            b0 = a_lo // W * W
            rows = self._view(b0, f_hi + h)
            sums = window_sums(self._features(rows), (a_lo - b0, a_hi - b0), W)
            cnt = sums[:, 0]
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = sums[:, 1:7] / cnt[:, None]
                second = sums[:, 7:13] / cnt[:, None]
                var = second - mean * mean
            # E[x^2] - E[x]^2 over sums of W terms is off by up to about W/4 ulp of E[x^2]
            # (x is relative to the reference frame). Take that rounding off, so a constant
            # window reads exactly 0 at any offset and passes a threshold of 0 (noiseless data).
            var = np.maximum(var - (2 * W * EPS) * second, 0.0)
            measured = cnt >= g.n_min
            sl = slice(f_lo - lo, f_hi - lo)
            n[sl] = cnt
            tra[sl] = np.where(measured, var[:, 3:6].sum(axis=1), np.inf)
            trg[sl] = np.where(measured, var[:, 0:3].sum(axis=1), np.inf)
        stats = self._view(lo, hi)
        stats[:, COL_TRA], stats[:, COL_TRG] = tra, trg  # kept for the windows' mean trace
        if self._on_traces is not None:
            self._on_traces(
                first_index=lo,
                time_s=stats[:, COL_T] - self._t0,
                gyro=stats[:, COL_G],
                accel=stats[:, COL_A],
                temperature_c=stats[:, COL_TEMP],
                valid=stats[:, COL_VALID] > 0,
                accel_trace=tra,
                gyro_trace=trg,
            )
        self._next_center = hi
        if self._accel_track is not None:  # the same frames, the same traces: computed once
            self._accel_track._shared.append((lo, n, tra, trg))
        return lo, n, tra, trg

    def _features(self, rows: np.ndarray) -> np.ndarray:
        """Per frame: validity, then values and squares relative to the reference frame."""
        w = rows[:, COL_VALID] > 0
        f = np.zeros((rows.shape[0], 13))
        if self._g_ref is not None:
            f[:, 0] = w
            rel = np.concatenate(
                (rows[:, COL_G] - self._g_ref, rows[:, COL_A] - self._a_ref), axis=1
            )
            rel[~w] = 0.0  # invalid frames carry no weight and may hold garbage
            f[:, 1:7] = rel
            f[:, 7:13] = rel * rel
        return f
