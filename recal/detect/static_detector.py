"""Static-window detector: finds the still periods of an IMU recording and averages them.

Pure numpy on arrays already in memory (no I/O). A frame index ``c`` is *quiet* when the moving
variance of the accelerometer and of the gyro, over a centred window of ``W`` frames, stays
below a threshold; the statistic per triad is the trace of the moving covariance (the sum of the
three per-axis variances), which does not depend on the triad's orientation. Runs of quiet frames
are trimmed by ``edge_trim_s`` at both ends and kept when at least ``min_duration_s`` remains.

Thresholds are given, or k times a noise floor: learned from an initial still period (the
median of the statistic over it, the idea of imu_tk), given as a :class:`NoiseFloor`, or, with
none of these, learned from the recording itself by :func:`estimate_noise_floor` (the median
trace of its quietest blocks; :func:`detect_static` does that first pass itself).

Per-triad stillness: a stretch where the accelerometer is quiet but the gyro is not (a unit held
by hand: the tremor shows on the gyro, far less on gravity) is still a pose for the
accelerometer. A second track judges the accelerometer alone; each of its runs in which the
both-triad track kept no window becomes an *accelerometer-only* window (``Window.gyro_still``
False, column ``gyro_still`` = 0): the accelerometer fit uses it, the gyro's static invariants do
not, and the slews may still start and end there. Runs where both triads are still give windows
exactly as before (a turn about the vertical, which the accelerometer cannot see, still splits
two poses). :class:`DetectionReport` counts the accelerometer's still stretches (the poses seen)
and says what became of each.

Faults: an invalid-status frame, or a sequence gap (``lost_before > 0``), longer than
``max_gap_frames`` (default 5) *splits* a static run like a motion edge (with the same edge
trim). A piece that is then too short is rejected and counted under that fault. Shorter holes are
bridged: the missing or invalid frames are left out of every statistic and counted in the
window's ``frames_lost`` / ``frames_invalid``.

Each window also gets the standard error of its means with correlated noise included, from
Allan statistics over blocks of its own frames; :func:`pooled_standard_errors` pools them over a
recording. The noise modelling lives in :mod:`recal.detect.noise` (docs/engine.md, "Correlated noise");
it is imported for the detector by :mod:`recal.detect.static_pieces`.

:class:`StaticDetector` keeps its input, thresholds and labels here; its parts are bases in
modules of their own: the geometry and moving-variance traces (:mod:`recal.detect.static_traces`),
the rejections by cause (:mod:`recal.detect.static_rejections`), the trimmed runs and their
windows (:mod:`recal.detect.static_pieces`) and the accelerometer-only windows
(:mod:`recal.detect.static_accel_only`).

:class:`StaticDetector` is the one implementation; :func:`detect_static` feeds it the whole
recording in slices. Decisions are made from chunk-independent sums (van Herk blocks aligned on
the global frame index, exact integer counts), so any chunking yields the same windows; the
window means agree to rounding (about 1e-15 relative).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from recal.detect.floor import estimate_noise_floor
from recal.detect.frames import SLICE_FRAMES as _SLICE
from recal.detect.frames import frame_arrays
from recal.detect.static_accel_only import AccelOnlyWindows
from recal.detect.static_config import DetectorConfig
from recal.detect.static_pieces import PieceWindows
from recal.detect.static_rejections import RejectionCounts
from recal.detect.static_report import DetectionReport, DetectionResult
from recal.detect.static_sums import (
    COL_A,
    COL_G,
    COL_LOST,
    COL_T,
    COL_TEMP,
    COL_TRA,
    COL_VALID,
    NCOL,
    Piece,
)
from recal.detect.static_traces import Geometry, MovingTraces
from recal.detect.windows import Window
from recal.errors import RecalInputError


class StaticDetector(MovingTraces, RejectionCounts, PieceWindows, AccelOnlyWindows):
    """Incremental detector: ``feed`` chunks of frames, get windows as they close; ``flush``.

    Memory is bounded by the frames not yet decided: about two moving windows plus the edge trim,
    plus the initial still period while thresholds are being learned. An open window is kept as
    running sums, however long it lasts.

    ``on_traces``, when given, is called as each batch of frames gets its moving variance, in
    frame order, with keyword arguments: first_index (global index of the batch's first frame),
    time_s (from the session start), gyro and accel (n, 3) and temperature_c (n,) as fed, valid
    (n,) bool, accel_trace and gyro_trace (n,) moving-variance traces, (input units)^2 (inf where
    the window holds too few valid frames). The arrays are views: copy what is kept. It is how a
    report follows the whole recording without this class keeping it.
    """

    def __init__(self, config: DetectorConfig, on_traces=None) -> None:
        if not config.has_thresholds:
            raise RecalInputError(
                "the detector needs both accel and gyro thresholds, an initial still period "
                "(init_still_s) or a noise floor (estimate_noise_floor) to set them from"
            )
        self.config = config
        self.report = DetectionReport()
        self._on_traces = on_traces
        self._data = np.empty((0, NCOL))
        self._base = 0  # global index of _data[0]
        self._received = 0
        self._t0: float | None = None
        self._t_last = -math.inf
        self._geom: Geometry | None = None
        self._g_ref: np.ndarray | None = None
        self._a_ref: np.ndarray | None = None
        self._temp_ref = math.nan
        self._finished = False
        # Stage 1: moving statistics per centre frame.
        self._next_center = 0
        # Learning: per-centre statistics held until the still period is over.
        self._thr_a = config.accel_threshold
        self._thr_g = config.gyro_threshold
        floor = config.noise_floor
        self._learning = config.init_still_s is not None and floor is None
        given = self._thr_a is not None and self._thr_g is not None
        if given:
            source = "given"
        elif floor is not None:
            source = floor.source
            thr_a, thr_g = floor.thresholds(config.threshold_k)
            self._thr_a = thr_a if self._thr_a is None else self._thr_a
            self._thr_g = thr_g if self._thr_g is None else self._thr_g
        else:
            source = f"learned from the initial {config.init_still_s:g} s still period"
        if not given and (config.accel_threshold is not None or config.gyro_threshold is not None):
            source += f" ({'accel' if config.accel_threshold is not None else 'gyro'} given)"
        self.report.threshold_source = source
        self.report.thresholds_learned = not given
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
        self._c_pieces = np.zeros((0, 3))  # and their (start_s, end_s, fault kind)
        self._qhist = np.zeros(0, dtype=bool)
        # Stage 3: trimmed runs and their running sums.
        self._next_m = 0
        self._prev_m = False
        self._piece: Piece | None = None
        self._out: list[Window] = []
        # Per-triad stillness: a second track on the accelerometer alone (the gyro vetoes
        # nothing there); its runs the both-triad track left without a window become
        # accelerometer-only windows (see _merge_accel).
        self._accel_track: StaticDetector | None = None
        self._shared: list[tuple] = []  # traces the detector that owns this track computed
        self._own_sem = True  # the accel track leaves it to the windows it hands on
        if config.accel_only_windows and self._thr_g != math.inf:
            track = replace(config, gyro_threshold=math.inf, accel_only_windows=False)
            self._accel_track = StaticDetector(track)
            self._accel_track._own_sem = False
        #: (start_s, end_s, None for a both-triad window, else the rejected stretch) of what
        #: this track decided near the accel track's undecided frames; pruned as it advances.
        self._covered: list[tuple[float, float, tuple | None]] = []
        self._stretches_seen = 0  # own rejected stretches already in _covered
        self._track_seen = 0  # the accel track's rejected stretches already merged

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
        t, g, a = frame_arrays(time_s, gyro, accel)
        n = t.shape[0]
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
            if self._accel_track is not None:  # slice by slice: it takes this one's traces
                self._merge_accel(self._accel_track.feed(t[sl], g[sl], a[sl], **part))
        out, self._out = self._out, []
        return out

    def flush(self) -> list[Window]:
        """End of stream: close the open window (the last half window cannot be judged)."""
        if not self._finished:
            self._process(final=True)
            self._finished = True
            if self._accel_track is not None:
                self._merge_accel(self._accel_track.flush())
        out, self._out = self._out, []
        return out

    @property
    def buffered_frames(self) -> int:
        """Frames held in memory (not yet decided, or needed by a moving window)."""
        track = 0 if self._accel_track is None else self._accel_track.buffered_frames
        return int(self._data.shape[0]) + track

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
        rows = np.empty((n, NCOL))
        rows[:, COL_T] = t
        rows[:, COL_G] = g
        rows[:, COL_A] = a
        ok = np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1)
        if valid is not None:
            ok &= valid.astype(bool)
        rows[:, COL_VALID] = ok
        rows[:, COL_TEMP] = np.nan if temperature_c is None else temperature_c
        lost = np.zeros(n) if lost_before is None else lost_before.astype(np.float64)
        if (lost < 0).any() or not np.isfinite(lost).all():
            raise RecalInputError("lost_before must hold frame counts >= 0")
        rows[:, COL_LOST] = lost
        rows[:, COL_TRA:] = np.nan
        if n:
            if self._t0 is None:
                self._t0 = float(t[0])
            self._t_last = float(t[-1])
            if self._g_ref is None and ok.any():
                # Sums are taken relative to the first valid frame, so raw counts keep precision.
                first = int(np.argmax(ok))
                self._g_ref, self._a_ref = g[first].copy(), a[first].copy()
            if math.isnan(self._temp_ref):
                finite = ok & np.isfinite(rows[:, COL_TEMP])
                if finite.any():
                    self._temp_ref = float(rows[int(np.argmax(finite)), COL_TEMP])
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

    def _maybe_learn(self, final: bool) -> None:
        cfg, g = self.config, self._geom
        if not self._pending:
            if final:
                self._raise_short()
            return
        lo = self._pending[0][0]
        hi = self._pending[-1][0] + self._pending[-1][1].shape[0]
        t = self._view(lo, hi)[:, COL_T] - self._t0
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
        ok = still[:, COL_VALID] > 0
        self._gyro_ref = still[ok][:, COL_G].mean(axis=0)
        rep = self.report
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
        valid = rows[:, COL_VALID] > 0
        idx = np.arange(lo, lo + n.shape[0])
        last_valid = np.maximum.accumulate(np.where(valid, idx, self._last_valid))
        if idx.size:
            self._last_valid = int(last_valid[-1])
        fault = np.zeros(n.shape[0], dtype=np.int8)
        fault[rows[:, COL_LOST] > tol] = 2
        fault[~valid & (idx - last_valid > tol)] = 1
        vq = (n >= g.n_min) & (tra <= self._thr_a) & (trg <= self._thr_g)
        q = vq & (fault == 0)
        self._count_rejections(lo, vq, q, fault)
        self._trim(lo, q, final=False)


def detect_static(
    time_s: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    temperature_c: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    lost_before: np.ndarray | None = None,
    *,
    config: DetectorConfig | None = None,
) -> DetectionResult:
    """Find the static windows of a whole recording (gyro and accel (N, 3), any units).

    With no thresholds, no initial still period and no noise floor in ``config``, the noise
    floor is first estimated from the recording itself (:func:`estimate_noise_floor`).
    """
    config = DetectorConfig() if config is None else config
    if not config.has_thresholds:
        floor = estimate_noise_floor(
            time_s,
            gyro,
            accel,
            valid,
            window_s=config.window_s,
            sample_rate_hz=config.sample_rate_hz,
        )
        config = replace(config, noise_floor=floor)
    det = StaticDetector(config)
    windows = det.feed(time_s, gyro, accel, temperature_c, valid, lost_before)
    windows += det.flush()
    return DetectionResult(windows=windows, report=det.report)
