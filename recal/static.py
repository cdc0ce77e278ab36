"""Static-window detector: finds the still periods of an IMU recording and averages them.

Pure numpy on arrays already in memory (no I/O). A frame index ``c`` is *quiet* when the moving
variance of the accelerometer and of the gyro, over a centred window of ``W`` frames, stays
below a threshold; the statistic per triad is the trace of the moving covariance (the sum of the
three per-axis variances), which does not depend on the triad's orientation. Runs of quiet frames
are trimmed by ``edge_trim_s`` at both ends and kept when at least ``min_duration_s`` remains.

Thresholds are given, or learned from an initial still period: ``threshold_k`` times the median
of the statistic over that period (the idea of imu_tk, with a median so that one bump in the
still period does not raise the bar).

Faults: an invalid-status frame, or a sequence gap (``lost_before > 0``), longer than
``max_gap_frames`` (default 0: every one) *splits* a static run like a motion edge (with the same
edge trim). A piece that is then too short is rejected and counted under that fault. Shorter
holes are tolerated: the missing or invalid frames are left out of every statistic and counted in
the window's ``frames_lost`` / ``frames_invalid``.

:class:`StaticDetector` is the one implementation; :func:`detect_static` feeds it the whole
recording in slices. Decisions are made from chunk-independent sums (van Herk blocks aligned on
the global frame index, exact integer counts), so any chunking yields the same windows; the
window means agree to rounding (about 1e-15 relative).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from recal.errors import RecalInputError
from recal.positions import (
    ACCEL_COLUMNS,
    ACCEL_STD_COLUMNS,
    GYRO_COLUMNS,
    GYRO_STD_COLUMNS,
)

#: Reasons a static run is rejected, as keys of :attr:`DetectionReport.rejected`.
REJECT_REASONS = ("too_short", "invalid_status", "sequence_gap", "rotating")
#: Columns beyond conventions section 4 that :func:`windows_to_columns` adds.
EXTRA_COLUMNS = ("frames_lost", "frames_invalid")

_RATE_PROBE = 1024  # time steps the sample rate is derived from (the same for every chunking)
_SLICE = 1 << 16  # frames processed per internal step: bounds the temporaries
_EPS = float(np.finfo(np.float64).eps)

# Raw row layout kept in the buffer.
_T, _G, _A, _TEMP, _VALID, _LOST = 0, slice(1, 4), slice(4, 7), 7, 8, 9
_NCOL = 10
_FAULT_NAMES = {1: "invalid_status", 2: "sequence_gap"}


@dataclass(frozen=True)
class DetectorConfig:
    """How static windows are found. Durations in s; thresholds in (input units)^2.

    window_s: length of the centred moving-variance window (1 s: long enough to average the
        noise to about 8 % spread at 100 Hz, short enough to localise a stop).
    min_duration_s: shortest window kept, after trimming.
    edge_trim_s: dropped at both ends of a run (and next to a fault). The run already starts
        half a window after the last loud frame; the trim also drops the settling tail that stays
        below the threshold.
    accel_threshold, gyro_threshold: explicit limits on the moving-variance trace. Each one not
        given is learned from the initial still period (``init_still_s`` is then required).
    init_still_s: the recording starts with this long a still period (imu_tk uses 50 s).
    threshold_k: learned threshold = k x median moving-variance trace of the still period. On
        white noise that statistic spreads about 8 % (W = 101) and real still periods reach
        1.3x the median; poses of the Xsens recording reach 3.5x from settling, so 5 leaves
        headroom while a disturbance of twice the noise RMS is already rejected.
    sample_rate_hz: frames per second; derived from the median time step of the first 1024
        frames when not given.
    max_gap_frames: longest hole (consecutive invalid frames, or frames lost in one gap) a
        window may contain; a longer one splits the run.
    gyro_rate_max: when set, reject a window whose mean gyro differs from the reference (the
        still-period mean when learning, else zero) by more than this, in gyro units (vector
        norm). Variance cannot see a steady rotation about the gravity vector; this can.
    """

    window_s: float = 1.0
    min_duration_s: float = 1.0
    edge_trim_s: float = 0.5
    accel_threshold: float | None = None
    gyro_threshold: float | None = None
    init_still_s: float | None = None
    threshold_k: float = 5.0
    sample_rate_hz: float | None = None
    max_gap_frames: int = 0
    gyro_rate_max: float | None = None

    def __post_init__(self) -> None:
        positive = {
            "window_s": self.window_s,
            "min_duration_s": self.min_duration_s,
            "threshold_k": self.threshold_k,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise RecalInputError(f"detector {name} must be a positive number, not {value}")
        optional_positive = {
            "init_still_s": self.init_still_s,
            "sample_rate_hz": self.sample_rate_hz,
            "gyro_rate_max": self.gyro_rate_max,
        }
        for name, value in optional_positive.items():
            if value is not None and not (math.isfinite(value) and value > 0):
                raise RecalInputError(f"detector {name} must be a positive number, not {value}")
        for name in ("accel_threshold", "gyro_threshold"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise RecalInputError(f"detector {name} must be a number >= 0, not {value}")
        if not (math.isfinite(self.edge_trim_s) and self.edge_trim_s >= 0):
            raise RecalInputError(f"detector edge_trim_s must be >= 0, not {self.edge_trim_s}")
        if int(self.max_gap_frames) != self.max_gap_frames or self.max_gap_frames < 0:
            raise RecalInputError(
                f"detector max_gap_frames must be a whole number >= 0, not {self.max_gap_frames}"
            )
        if self.init_still_s is None and (
            self.accel_threshold is None or self.gyro_threshold is None
        ):
            raise RecalInputError(
                "the detector needs both accel and gyro thresholds, or an initial still period "
                "(init_still_s) to learn them from"
            )


@dataclass(frozen=True, eq=False)
class Window:
    """One static window. Means and standard deviations in input units, shape (3,).

    start_s / end_s: times of the first and last frame averaged, from the session start (the
    first frame fed). start_index / end_index: their frame indices (inclusive). samples: frames
    averaged (valid ones). std: per-sample standard deviation (ddof 1). temperature_c: mean of the
    finite temperatures (NaN without any); temperature_rate_c_per_h: least-squares slope over
    time (NaN with fewer than two). frames_lost / frames_invalid: tolerated holes inside.
    """

    start_s: float
    end_s: float
    start_index: int
    end_index: int
    samples: int
    gyro: np.ndarray
    accel: np.ndarray
    gyro_std: np.ndarray
    accel_std: np.ndarray
    temperature_c: float
    temperature_rate_c_per_h: float
    frames_lost: int
    frames_invalid: int

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass
class DetectionReport:
    """What the detector saw and decided; counts accumulate as frames are fed."""

    frames: int = 0
    invalid_frames: int = 0
    lost_frames: int = 0
    gaps: int = 0
    windows_kept: int = 0
    rejected: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REJECT_REASONS, 0))
    sample_rate_hz: float | None = None
    window_samples: int | None = None
    accel_threshold: float | None = None
    gyro_threshold: float | None = None
    thresholds_learned: bool = False
    gyro_reference: np.ndarray | None = None
    duration_s: float = 0.0

    def summary_lines(self) -> list[str]:
        """Plain-words summary, a few lines, for a log or the command line."""
        rate = f"{self.sample_rate_hz:.6g} Hz" if self.sample_rate_hz else "rate unknown"
        lines = [
            f"frames: {self.frames} ({self.duration_s:.1f} s at {rate}); "
            f"invalid status {self.invalid_frames}, lost {self.lost_frames} in {self.gaps} gaps"
        ]
        if self.accel_threshold is not None and self.gyro_threshold is not None:
            how = "learned" if self.thresholds_learned else "given"
            lines.append(
                f"thresholds on the moving-variance trace over {self.window_samples} frames "
                f"({how}): accel {self.accel_threshold:.4g}, gyro {self.gyro_threshold:.4g}"
            )
        reasons = ", ".join(f"{k} {v}" for k, v in self.rejected.items())
        lines.append(f"windows: {self.windows_kept} kept; rejected: {reasons}")
        return lines


@dataclass
class DetectionResult:
    windows: list[Window]
    report: DetectionReport


@dataclass(frozen=True)
class _Geometry:
    rate: float
    h: int  # half window; W = 2h + 1
    trim: int
    required: int  # frames a kept window needs
    n_min: int  # valid frames a moving window needs to count as measured

    @property
    def W(self) -> int:  # noqa: N802 - the window length is W throughout the docs
        return 2 * self.h + 1


@dataclass
class _Piece:
    """A trimmed run being summed: frame range, first/last times, value reference, sums."""

    first: int
    last: int
    t_first: float
    t_last: float
    g_ref: np.ndarray
    a_ref: np.ndarray
    sums: np.ndarray


class StaticDetector:
    """Incremental detector: ``feed`` chunks of frames, get windows as they close; ``flush``.

    Memory is bounded by the frames not yet decided: about two moving windows plus the edge trim,
    plus the initial still period while thresholds are being learned. An open window is kept as
    running sums, however long it lasts.
    """

    def __init__(self, config: DetectorConfig) -> None:
        self.config = config
        self.report = DetectionReport()
        self._data = np.empty((0, _NCOL))
        self._base = 0  # global index of _data[0]
        self._received = 0
        self._t0: float | None = None
        self._t_last = -math.inf
        self._geom: _Geometry | None = None
        self._g_ref: np.ndarray | None = None
        self._a_ref: np.ndarray | None = None
        self._temp_ref = math.nan
        self._finished = False
        # Stage 1: moving statistics per centre frame.
        self._next_center = 0
        # Learning: per-centre statistics held until the still period is over.
        self._thr_a = config.accel_threshold
        self._thr_g = config.gyro_threshold
        self._learning = config.init_still_s is not None
        self._pending: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
        self._gyro_ref = np.zeros(3)
        # Stage 2: labels, faults and rejection bookkeeping.
        self._last_valid = -1
        self._prev_vq = False
        self._prev_q = False
        self._prev_fault = 0
        self._q_open: tuple[int, int] | None = None  # (start, fault kind on its left)
        self._c_open: int | None = None  # start of the open quiet candidate
        self._c_pending = np.zeros(3, dtype=np.int64)  # short pieces in it, by fault kind
        self._qhist = np.zeros(0, dtype=bool)
        # Stage 3: trimmed runs and their running sums.
        self._next_m = 0
        self._prev_m = False
        self._piece: _Piece | None = None
        self._out: list[Window] = []

    # ---- public ---------------------------------------------------------------------------
    def feed(
        self,
        time_s: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        temperature_c: np.ndarray | None = None,
        valid: np.ndarray | None = None,
        lost_before: np.ndarray | None = None,
    ) -> list[Window]:
        """Add frames (time in s, gyro and accel (N, 3)); return the windows that closed."""
        if self._finished:
            raise RecalInputError("the detector was flushed; start a new one for a new stream")
        t = np.asarray(time_s, dtype=np.float64).reshape(-1)
        n = t.shape[0]
        g = np.asarray(gyro, dtype=np.float64)
        a = np.asarray(accel, dtype=np.float64)
        if g.shape != (n, 3) or a.shape != (n, 3):
            raise RecalInputError(
                f"gyro and accel must have shape ({n}, 3) like time_s; got {g.shape} and {a.shape}"
            )
        extra = {
            "temperature_c": temperature_c,
            "valid": valid,
            "lost_before": lost_before,
        }
        for name, values in extra.items():
            if values is not None:
                extra[name] = np.asarray(values).reshape(-1)
                if extra[name].shape[0] != n:
                    raise RecalInputError(
                        f"{name} has {extra[name].shape[0]} values for {n} frames"
                    )
        # Slice by slice: bounded temporaries however much is fed at once.
        for lo in range(0, n, _SLICE):
            sl = slice(lo, lo + _SLICE)
            part = {k: (None if v is None else v[sl]) for k, v in extra.items()}
            self._append(self._rows(t[sl], g[sl], a[sl], **part))
            self._process(final=False)
        out, self._out = self._out, []
        return out

    def flush(self) -> list[Window]:
        """End of stream: close the open window (the last half window cannot be judged)."""
        if not self._finished:
            self._process(final=True)
            self._finished = True
        out, self._out = self._out, []
        return out

    @property
    def buffered_frames(self) -> int:
        """Frames held in memory (not yet decided, or needed by a moving window)."""
        return int(self._data.shape[0])

    # ---- input ----------------------------------------------------------------------------
    def _rows(
        self,
        t: np.ndarray,
        g: np.ndarray,
        a: np.ndarray,
        temperature_c: np.ndarray | None,
        valid: np.ndarray | None,
        lost_before: np.ndarray | None,
    ) -> np.ndarray:
        """Checked frames as buffer rows; updates the references and the report's counts."""
        n = t.shape[0]
        if not np.isfinite(t).all():
            i = int(np.argmax(~np.isfinite(t)))
            raise RecalInputError(
                f"time_s has a NaN or infinite value at frame {self._received + i}"
            )
        steps = np.diff(t, prepend=self._t_last)
        if n and (steps <= 0).any():
            i = int(np.argmax(steps <= 0))
            raise RecalInputError(
                f"time must increase: frame {self._received + i} at {t[i]} s "
                "does not come after the previous one"
            )
        rows = np.empty((n, _NCOL))
        rows[:, _T] = t
        rows[:, _G] = g
        rows[:, _A] = a
        ok = np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1)
        if valid is not None:
            ok &= valid.astype(bool)
        rows[:, _VALID] = ok
        rows[:, _TEMP] = np.nan if temperature_c is None else temperature_c
        lost = np.zeros(n) if lost_before is None else lost_before.astype(np.float64)
        if (lost < 0).any() or not np.isfinite(lost).all():
            raise RecalInputError("lost_before must hold frame counts >= 0")
        rows[:, _LOST] = lost
        if n:
            if self._t0 is None:
                self._t0 = float(t[0])
            self._t_last = float(t[-1])
            if self._g_ref is None and ok.any():
                # Sums are taken relative to the first valid frame, so raw counts keep precision.
                first = int(np.argmax(ok))
                self._g_ref, self._a_ref = g[first].copy(), a[first].copy()
            if math.isnan(self._temp_ref):
                finite = ok & np.isfinite(rows[:, _TEMP])
                if finite.any():
                    self._temp_ref = float(rows[int(np.argmax(finite)), _TEMP])
        rep = self.report
        rep.frames += n
        rep.invalid_frames += int(n - ok.sum())
        rep.lost_frames += int(lost.sum())
        rep.gaps += int((lost > 0).sum())
        if self._t0 is not None:
            rep.duration_s = self._t_last - self._t0
        return rows

    def _append(self, rows: np.ndarray) -> None:
        self._data = np.concatenate((self._data, rows)) if self._data.size else rows.copy()
        self._received += rows.shape[0]

    def _view(self, lo: int, hi: int) -> np.ndarray:
        return self._data[lo - self._base : hi - self._base]

    def _drop_before(self, index: int) -> None:
        k = index - self._base
        if k > 0:
            self._data = self._data[k:]
            self._base = index

    # ---- pipeline -------------------------------------------------------------------------
    def _process(self, final: bool) -> None:
        if self._geom is None and not self._set_geometry(final):
            return
        centres = self._moving_stats(final)
        if centres is not None and self._learning:
            self._pending.append(centres)
        elif centres is not None:
            self._label(*centres)
        if self._learning:
            self._maybe_learn(final)
        if final:
            self._trim(self._received, np.zeros(0, dtype=bool), final=True)
        g = self._geom
        keep = max(0, (self._next_center - g.h) // g.W * g.W)
        self._drop_before(min(keep, self._next_m))

    def _set_geometry(self, final: bool) -> bool:
        cfg = self.config
        rate = cfg.sample_rate_hz
        if rate is None:
            n = min(self._received, _RATE_PROBE + 1)
            if n < _RATE_PROBE + 1 and not final:
                return False
            if n < 2:
                return False
            rate = 1.0 / float(np.median(np.diff(self._view(0, n)[:, _T])))
        h = max(1, round(cfg.window_s * rate / 2))
        self._geom = _Geometry(
            rate=rate,
            h=h,
            trim=max(0, round(cfg.edge_trim_s * rate)),
            required=max(2, round(cfg.min_duration_s * rate)),
            n_min=h + 1,
        )
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
        n = np.zeros(hi - lo)
        tra = np.full(hi - lo, np.inf)
        trg = np.full(hi - lo, np.inf)
        f_lo, f_hi = max(lo, h), min(hi, M - h)  # centres with a full window
        if f_hi > f_lo:
            a_lo, a_hi = f_lo - h, f_hi - h  # window starts
            b0 = a_lo // W * W
            rows = self._view(b0, f_hi + h)
            sums = _window_sums(self._features(rows), (a_lo - b0, a_hi - b0), W)
            cnt = sums[:, 0]
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = sums[:, 1:7] / cnt[:, None]
                second = sums[:, 7:13] / cnt[:, None]
                var = second - mean * mean
            # E[x^2] - E[x]^2 over sums of W terms is off by up to about W/4 ulp of E[x^2]
            # (x is relative to the reference frame). Take that rounding off, so a constant
            # window reads exactly 0 at any offset and passes a threshold of 0 (noiseless data).
            var = np.maximum(var - (2 * W * _EPS) * second, 0.0)
            measured = cnt >= g.n_min
            sl = slice(f_lo - lo, f_hi - lo)
            n[sl] = cnt
            tra[sl] = np.where(measured, var[:, 3:6].sum(axis=1), np.inf)
            trg[sl] = np.where(measured, var[:, 0:3].sum(axis=1), np.inf)
        self._next_center = hi
        return lo, n, tra, trg

    def _features(self, rows: np.ndarray) -> np.ndarray:
        """Per frame: validity, then values and squares relative to the reference frame."""
        w = rows[:, _VALID] > 0
        f = np.zeros((rows.shape[0], 13))
        if self._g_ref is not None:
            f[:, 0] = w
            rel = np.concatenate((rows[:, _G] - self._g_ref, rows[:, _A] - self._a_ref), axis=1)
            rel[~w] = 0.0  # invalid frames carry no weight and may hold garbage
            f[:, 1:7] = rel
            f[:, 7:13] = rel * rel
        return f

    def _maybe_learn(self, final: bool) -> None:
        cfg, g = self.config, self._geom
        if not self._pending:
            if final:
                self._raise_short()
            return
        lo = self._pending[0][0]
        hi = self._pending[-1][0] + self._pending[-1][1].shape[0]
        t = self._view(lo, hi)[:, _T] - self._t0
        if not final and t[-1] < cfg.init_still_s:
            return
        n = np.concatenate([p[1] for p in self._pending])
        tra = np.concatenate([p[2] for p in self._pending])
        trg = np.concatenate([p[3] for p in self._pending])
        if t[-1] < cfg.init_still_s:
            self._raise_short()
        sel = (t < cfg.init_still_s) & (n >= g.n_min)
        if not sel.any():
            raise RecalInputError(
                f"the initial still period ({cfg.init_still_s} s) is shorter than one moving "
                f"window ({g.W} frames) of valid frames: cannot learn thresholds"
            )
        if self._thr_a is None:
            self._thr_a = cfg.threshold_k * float(np.median(tra[sel]))
        if self._thr_g is None:
            self._thr_g = cfg.threshold_k * float(np.median(trg[sel]))
        still = self._view(0, lo + int(np.flatnonzero(t < cfg.init_still_s)[-1]) + 1)
        ok = still[:, _VALID] > 0
        self._gyro_ref = still[ok][:, _G].mean(axis=0)
        rep = self.report
        rep.thresholds_learned = cfg.accel_threshold is None or cfg.gyro_threshold is None
        rep.gyro_reference = self._gyro_ref.copy()
        self._learning = False
        pending, self._pending = self._pending, []
        for centres in pending:
            self._label(*centres)

    def _raise_short(self) -> None:
        raise RecalInputError(
            f"the recording ({self.report.duration_s:.1f} s) ends before the initial still "
            f"period of {self.config.init_still_s} s the thresholds are learned from"
        )

    def _label(self, lo: int, n: np.ndarray, tra: np.ndarray, trg: np.ndarray) -> None:
        """Quiet / fault labels for frames [lo, lo + len(n)), then runs and trimming."""
        rep = self.report
        if rep.accel_threshold is None:
            rep.accel_threshold, rep.gyro_threshold = self._thr_a, self._thr_g
        g = self._geom
        tol = self.config.max_gap_frames
        rows = self._view(lo, lo + n.shape[0])
        valid = rows[:, _VALID] > 0
        idx = np.arange(lo, lo + n.shape[0])
        last_valid = np.maximum.accumulate(np.where(valid, idx, self._last_valid))
        if idx.size:
            self._last_valid = int(last_valid[-1])
        fault = np.zeros(n.shape[0], dtype=np.int8)
        fault[rows[:, _LOST] > tol] = 2
        fault[~valid & (idx - last_valid > tol)] = 1
        vq = (n >= g.n_min) & (tra <= self._thr_a) & (trg <= self._thr_g)
        q = vq & (fault == 0)
        self._count_rejections(lo, vq, q, fault)
        self._trim(lo, q, final=False)

    def _count_rejections(self, lo: int, vq, q, fault) -> None:
        """Count quiet pieces too short to keep, by why they are short.

        A candidate is a run of quiet frames ignoring faults. If even the whole candidate is too
        short, that is one "too_short". Otherwise each piece cut too short by a fault counts
        under that fault ("invalid_status" or "sequence_gap").
        """
        g = self._geom
        if vq.size == 0:
            return
        need = g.required + 2 * g.trim
        # Runs of q (pieces) that close here, with the fault on their left and right.
        q_st, q_en = _edges(self._prev_q, q)
        left = np.where(q_st > 0, fault[np.maximum(q_st - 1, 0)], self._prev_fault)
        starts, lefts = q_st + lo, left.astype(np.int64)
        if self._q_open is not None:
            starts = np.concatenate(([self._q_open[0]], starts))
            lefts = np.concatenate(([self._q_open[1]], lefts))
        closed = q_en.shape[0]
        p_start, p_left = starts[:closed], lefts[:closed]
        p_len = q_en + lo - p_start
        p_right = fault[q_en].astype(np.int64)
        self._q_open = (int(starts[-1]), int(lefts[-1])) if starts.shape[0] > closed else None
        short = p_len < need
        cause = np.where(p_left != 0, p_left, p_right)[short]
        p_short_start = p_start[short]
        # Candidates (runs of vq) and which one holds each short piece.
        c_st, c_en = _edges(self._prev_vq, vq)
        c_starts = c_st + lo
        carried = self._c_open is not None
        if carried:
            c_starts = np.concatenate(([self._c_open], c_starts))
        c_closed = c_en.shape[0]
        c_len = c_en + lo - c_starts[:c_closed]
        owner = np.searchsorted(c_starts, p_short_start, side="right") - 1
        per_c = np.zeros((c_starts.shape[0], 3), dtype=np.int64)
        np.add.at(per_c, (owner, cause), 1)
        if carried:
            per_c[0] += self._c_pending
        rejected = self.report.rejected
        long_c = c_len >= need
        rejected["too_short"] += int((~long_c).sum()) + int(per_c[:c_closed][long_c, 0].sum())
        for kind, name in _FAULT_NAMES.items():
            rejected[name] += int(per_c[:c_closed][long_c, kind].sum())
        if c_starts.shape[0] > c_closed:
            self._c_open, self._c_pending = int(c_starts[-1]), per_c[-1]
        else:
            self._c_open, self._c_pending = None, np.zeros(3, dtype=np.int64)
        self._prev_vq, self._prev_q, self._prev_fault = bool(vq[-1]), bool(q[-1]), int(fault[-1])

    def _trim(self, lo: int, q: np.ndarray, final: bool) -> None:
        """Erode the pieces by the edge trim: frame j is kept when q holds on [j-T, j+T]."""
        T = self._geom.trim
        ext = np.concatenate((self._qhist, q))
        ext_lo = self._next_m - T  # global index of ext[0]
        hi = lo + q.shape[0]
        if final:
            ext = np.concatenate((ext, np.zeros(T, dtype=bool)))  # nothing after the end
        else:
            hi -= T
        if hi <= self._next_m:
            self._qhist = ext
            return
        loud = np.concatenate(([0], np.cumsum(~ext, dtype=np.int64)))
        j = np.arange(self._next_m, hi) - ext_lo
        m = (loud[j + T + 1] - loud[j - T]) == 0
        d0 = self._next_m
        self._next_m = hi
        self._qhist = ext[hi - T - ext_lo : hi + T - ext_lo] if not final else ext[:0]
        self._accumulate(d0, m, final)

    def _accumulate(self, d0: int, m: np.ndarray, final: bool) -> None:
        """Add kept frames [d0, d0 + len(m)) to running sums; finish the windows that close."""
        rows = self._view(d0, d0 + m.shape[0])
        st, en = _edges(self._prev_m, m)
        piece = self._piece
        if piece is not None and (en.shape[0] and en[0] == 0):
            self._finish(piece)  # closed right at the chunk boundary
            piece = None
            en = en[1:]
        sel = np.flatnonzero(m)
        if sel.size:
            cont = piece is not None  # the first segment continues the open piece
            seg_starts = np.concatenate(([0], st)) if cont else st
            seg_pos = np.searchsorted(sel, seg_starts)
            seg_id = np.searchsorted(seg_starts, sel, side="right") - 1
            first_rows = rows[seg_starts]
            t_first = first_rows[:, _T].copy()
            g_ref = first_rows[:, _G].copy()
            a_ref = first_rows[:, _A].copy()
            bad_ref = first_rows[:, _VALID] == 0  # an invalid first frame may hold garbage
            g_ref[bad_ref], a_ref[bad_ref] = self._g_ref, self._a_ref
            if cont:
                t_first[0], g_ref[0], a_ref[0] = piece.t_first, piece.g_ref, piece.a_ref
            prev_in = np.concatenate(([self._prev_m], m[:-1]))[sel]
            feats = _piece_features(
                rows[sel],
                prev_in,
                t_first[seg_id],
                g_ref[seg_id],
                a_ref[seg_id],
                0.0 if math.isnan(self._temp_ref) else self._temp_ref,
            )
            sums = np.add.reduceat(feats, seg_pos, axis=0)
            ends = np.concatenate((en, [m.shape[0]])) if m[-1] else en
            for k in range(seg_starts.shape[0]):
                last = d0 + int(ends[k]) - 1
                if k == 0 and cont:
                    piece.sums = piece.sums + sums[0]
                    piece.last, piece.t_last = last, float(rows[ends[k] - 1, _T])
                else:
                    piece = _Piece(
                        first=d0 + int(seg_starts[k]),
                        last=last,
                        t_first=float(t_first[k]),
                        t_last=float(rows[ends[k] - 1, _T]),
                        g_ref=g_ref[k],
                        a_ref=a_ref[k],
                        sums=sums[k],
                    )
                if k < seg_starts.shape[0] - 1 or not m[-1]:
                    self._finish(piece)
                    piece = None
        if final and piece is not None:
            self._finish(piece)
            piece = None
        self._piece = piece
        if m.size:
            self._prev_m = bool(m[-1])

    def _finish(self, piece: _Piece) -> None:
        """Turn a closed trimmed run into a window, or count why it is rejected."""
        g = self._geom
        if piece.last - piece.first + 1 < g.required:
            return  # already counted as a short piece when its quiet run closed
        s = piece.sums
        n = s[0]
        rejected = self.report.rejected
        if n < 2:
            rejected["invalid_status"] += 1
            return
        d_g, d_a = s[1:4] / n, s[7:10] / n
        gyro = piece.g_ref + d_g
        limit = self.config.gyro_rate_max
        if limit is not None and float(np.linalg.norm(gyro - self._gyro_ref)) > limit:
            rejected["rotating"] += 1
            return
        var_g = np.maximum(s[4:7] - s[1:4] * d_g, 0.0) / (n - 1)
        var_a = np.maximum(s[10:13] - s[7:10] * d_a, 0.0) / (n - 1)
        nt, st, stt, sv, stv = s[13:18]
        temp, rate = math.nan, math.nan
        if nt > 0:
            temp = sv / nt + self._temp_ref
            den = nt * stt - st * st
            if nt >= 2 and den > 0:
                rate = (nt * stv - st * sv) / den * 3600.0  # degC/s -> degC/h
        t0 = self._t0
        self._out.append(
            Window(
                start_s=piece.t_first - t0,
                end_s=piece.t_last - t0,
                start_index=piece.first,
                end_index=piece.last,
                samples=int(n),
                gyro=gyro,
                accel=piece.a_ref + d_a,
                gyro_std=np.sqrt(var_g),
                accel_std=np.sqrt(var_a),
                temperature_c=float(temp),
                temperature_rate_c_per_h=float(rate),
                frames_lost=int(s[19]),
                frames_invalid=int(s[18]),
            )
        )
        self.report.windows_kept += 1


def _edges(prev: bool, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local indices where runs of True start, and where they end (first False after)."""
    d = np.diff(mask.astype(np.int8), prepend=np.int8(prev))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def _window_sums(f: np.ndarray, starts: tuple[int, int], W: int) -> np.ndarray:
    """Sums of f over windows [a, a + W) for a in range(*starts), f starting block-aligned.

    van Herk: blocks of W frames aligned on the global index; a window is the suffix sum of one
    block plus the prefix sum of the next. The result depends only on the data of those two
    blocks, never on how the stream was chunked, and never accumulates rounding over the stream.
    """
    nb = -(-f.shape[0] // W)
    blocks = np.zeros((nb * W, f.shape[1]))
    blocks[: f.shape[0]] = f
    blocks = blocks.reshape(nb, W, f.shape[1])
    prefix = np.cumsum(blocks, axis=1)
    suffix = np.cumsum(blocks[:, ::-1], axis=1)[:, ::-1]
    a = np.arange(*starts)
    k, o = np.divmod(a, W)
    out = suffix[k, o]
    split = o > 0
    out[split] += prefix[k[split] + 1, o[split] - 1]
    return out


def _piece_features(rows, prev_in, t_first, g_ref, a_ref, temp_ref: float) -> np.ndarray:
    """Per kept frame, the terms whose sums give a window's means, variances and slope."""
    w = rows[:, _VALID] > 0
    f = np.zeros((rows.shape[0], 20))
    dg = np.where(w[:, None], rows[:, _G] - g_ref, 0.0)
    da = np.where(w[:, None], rows[:, _A] - a_ref, 0.0)
    f[:, 0] = w
    f[:, 1:4], f[:, 4:7] = dg, dg * dg
    f[:, 7:10], f[:, 10:13] = da, da * da
    temp = rows[:, _TEMP]
    wt = w & np.isfinite(temp)
    tau = np.where(wt, rows[:, _T] - t_first, 0.0)  # time from the window start, s
    theta = np.where(wt, temp - temp_ref, 0.0)
    f[:, 13], f[:, 14], f[:, 15] = wt, tau, tau * tau
    f[:, 16], f[:, 17] = theta, tau * theta
    f[:, 18] = ~w
    f[:, 19] = np.where(prev_in, rows[:, _LOST], 0.0)  # a gap between two kept frames
    return f


def detect_static(
    time_s: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    temperature_c: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    lost_before: np.ndarray | None = None,
    *,
    config: DetectorConfig,
) -> DetectionResult:
    """Find the static windows of a whole recording (gyro and accel (N, 3), any units)."""
    det = StaticDetector(config)
    windows = det.feed(time_s, gyro, accel, temperature_c, valid, lost_before)
    windows += det.flush()
    return DetectionResult(windows=windows, report=det.report)


def windows_to_columns(windows: Sequence[Window]) -> dict[str, np.ndarray]:
    """Positions-table columns (conventions section 4) plus frames_lost and frames_invalid.

    The temperature columns appear only when every window has a finite value.
    """
    cols: dict[str, np.ndarray] = {
        "start_s": np.array([w.start_s for w in windows], dtype=float),
        "end_s": np.array([w.end_s for w in windows], dtype=float),
        "samples": np.array([w.samples for w in windows], dtype=float),
    }
    for names, attr in (
        (GYRO_COLUMNS, "gyro"),
        (ACCEL_COLUMNS, "accel"),
        (GYRO_STD_COLUMNS, "gyro_std"),
        (ACCEL_STD_COLUMNS, "accel_std"),
    ):
        stack = np.array([getattr(w, attr) for w in windows], dtype=float).reshape(-1, 3)
        for j, name in enumerate(names):
            cols[name] = stack[:, j]
    for name in ("temperature_c", "temperature_rate_c_per_h"):
        values = np.array([getattr(w, name) for w in windows], dtype=float)
        if values.size and np.isfinite(values).all():
            cols[name] = values
    cols["frames_lost"] = np.array([w.frames_lost for w in windows], dtype=float)
    cols["frames_invalid"] = np.array([w.frames_invalid for w in windows], dtype=float)
    return cols
