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
it is imported here for the detector.

:class:`StaticDetector` is the one implementation; :func:`detect_static` feeds it the whole
recording in slices. Decisions are made from chunk-independent sums (van Herk blocks aligned on
the global frame index, exact integer counts), so any chunking yields the same windows; the
window means agree to rounding (about 1e-15 relative).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from recal.detect.floor import RATE_PROBE as _RATE_PROBE
from recal.detect.floor import estimate_noise_floor
from recal.detect.frames import SLICE_FRAMES as _SLICE
from recal.detect.frames import frame_arrays
from recal.detect.noise import allan_sums as _allan_sums
from recal.detect.static_accel_only import AccelOnlyWindows
from recal.detect.static_config import DetectorConfig
from recal.detect.static_report import DetectionReport, DetectionResult
from recal.detect.static_sums import (
    BLOCK_FEATS,
    COL_A,
    COL_G,
    COL_LOST,
    COL_T,
    COL_TEMP,
    COL_TRA,
    COL_TRG,
    COL_VALID,
    NCOL,
    Piece,
    add_blocks,
    allan_window_sem,
    piece_features,
    run_edges,
    window_sums,
)
from recal.detect.windows import Window
from recal.errors import RecalInputError

_EPS = float(np.finfo(np.float64).eps)
_FAULT_NAMES = {1: "invalid_status", 2: "sequence_gap"}


@dataclass(frozen=True)
class _Geometry:
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


class StaticDetector(AccelOnlyWindows):
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

    def _set_geometry(self, final: bool) -> bool:
        cfg = self.config
        rate = cfg.sample_rate_hz
        if rate is None:
            n = min(self._received, _RATE_PROBE + 1)
            if n < _RATE_PROBE + 1 and not final:
                return False
            if n < 2:
                return False
            rate = 1.0 / float(np.median(np.diff(self._view(0, n)[:, COL_T])))
        window_s, trim_s, min_s = cfg.durations(rate)
        h = max(1, round(window_s * rate / 2))
        self._geom = _Geometry(
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
            var = np.maximum(var - (2 * W * _EPS) * second, 0.0)
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
        q_st, q_en = run_edges(self._prev_q, q)
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
        c_st, c_en = run_edges(self._prev_vq, vq)
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
        short_len = c_len[~long_c]
        if short_len.size:
            self.report.short_stretches += int(short_len.size)
            longest = max(self.report.longest_short_frames, int(short_len.max()))
            self.report.longest_short_frames = longest
        rejected["too_short"] += int((~long_c).sum()) + int(per_c[:c_closed][long_c, 0].sum())
        for kind, name in _FAULT_NAMES.items():
            rejected[name] += int(per_c[:c_closed][long_c, kind].sum())
        if short.any() or (~long_c).any() or self._c_pieces.shape[0]:
            self._list_rejections(lo, q_en[short] + lo - 1, p_short_start, cause, owner,
                                  c_starts, c_en + lo - 1, long_c, carried)  # fmt: skip
        if c_starts.shape[0] > c_closed:
            self._c_open, self._c_pending = int(c_starts[-1]), per_c[-1]
        else:
            self._c_open, self._c_pending = None, np.zeros(3, dtype=np.int64)
        self._prev_vq, self._prev_q, self._prev_fault = bool(vq[-1]), bool(q[-1]), int(fault[-1])

    def _list_rejections(self, lo, p_last, p_first, cause, owner, c_first, c_last, long_c, carried):
        """The stretches behind the counts of :meth:`_count_rejections`, as session times.

        Short pieces wait with their candidate (times taken now, while their frames are held):
        they are listed under their fault once it closes long, else the candidate is one
        too_short stretch.
        """
        rep = self.report
        c_closed = c_last.shape[0]
        short_c = np.flatnonzero(~long_c)
        rep._add_stretches(self._times(c_first[short_c]), self._times(c_last[short_c]), "too_short")
        pieces = np.column_stack((self._times(p_first), self._times(p_last), cause))
        if carried:  # pieces of the candidate open before this call belong to owner 0
            pieces = np.concatenate((self._c_pieces, pieces))
            owner = np.concatenate((np.zeros(self._c_pieces.shape[0], dtype=owner.dtype), owner))
        done = owner < c_closed
        keep = np.zeros_like(done)
        keep[done] = long_c[owner[done]]
        names = np.array(["too_short", *_FAULT_NAMES.values()])
        listed = pieces[keep]
        rep._add_stretches(listed[:, 0], listed[:, 1], names[listed[:, 2].astype(int)])
        self._c_pieces = pieces[~done]

    def _times(self, index: np.ndarray) -> np.ndarray:
        """Session times (s) of frame indices; a frame no longer held is placed by the rate."""
        index = np.asarray(index, dtype=np.int64)
        if index.size == 0:
            return np.zeros(0)
        k = np.clip(index - self._base, 0, self._data.shape[0] - 1)
        held = self._data[k, COL_T] - self._t0
        before = self._data[0, COL_T] - self._t0 - (self._base - index) / self._geom.rate
        return np.where(index >= self._base, held, before)

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
        st, en = run_edges(self._prev_m, m)
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
            t_first = first_rows[:, COL_T].copy()
            g_ref = first_rows[:, COL_G].copy()
            a_ref = first_rows[:, COL_A].copy()
            bad_ref = first_rows[:, COL_VALID] == 0  # an invalid first frame may hold garbage
            g_ref[bad_ref], a_ref[bad_ref] = self._g_ref, self._a_ref
            if cont:
                t_first[0], g_ref[0], a_ref[0] = piece.t_first, piece.g_ref, piece.a_ref
            prev_in = np.concatenate(([self._prev_m], m[:-1]))[sel]
            feats = piece_features(
                rows[sel],
                prev_in,
                t_first[seg_id],
                g_ref[seg_id],
                a_ref[seg_id],
                0.0 if math.isnan(self._temp_ref) else self._temp_ref,
            )
            sums = np.add.reduceat(feats, seg_pos, axis=0)
            # Block sums for the Allan statistics: blocks aligned on the global frame index, so
            # every chunking cuts them alike; a block counts once all its frames are kept.
            B = self._geom.block
            bid = (d0 + sel) // B
            cut = np.ones(sel.shape[0], dtype=bool)
            cut[1:] = (bid[1:] != bid[:-1]) | (seg_id[1:] != seg_id[:-1])
            g_pos = np.flatnonzero(cut)
            g_sums = np.add.reduceat(feats[:, BLOCK_FEATS], g_pos, axis=0)
            g_len = np.diff(g_pos, append=sel.shape[0])
            g_of_seg = np.searchsorted(seg_id[g_pos], np.arange(seg_starts.shape[0] + 1))
            ends = np.concatenate((en, [m.shape[0]])) if m[-1] else en
            for k in range(seg_starts.shape[0]):
                last = d0 + int(ends[k]) - 1
                if k == 0 and cont:
                    piece.sums = piece.sums + sums[0]
                    piece.last, piece.t_last = last, float(rows[ends[k] - 1, COL_T])
                else:
                    piece = Piece(
                        first=d0 + int(seg_starts[k]),
                        last=last,
                        t_first=float(t_first[k]),
                        t_last=float(rows[ends[k] - 1, COL_T]),
                        g_ref=g_ref[k],
                        a_ref=a_ref[k],
                        sums=sums[k],
                    )
                closes = k < seg_starts.shape[0] - 1 or not m[-1]
                gs = slice(g_of_seg[k], g_of_seg[k + 1])
                add_blocks(piece, bid[g_pos[gs]], g_len[gs], g_sums[gs], B, still_open=not closes)
                if closes:
                    self._finish(piece)
                    piece = None
        if final and piece is not None:
            self._finish(piece)
            piece = None
        self._piece = piece
        if m.size:
            self._prev_m = bool(m[-1])

    def _finish(self, piece: Piece) -> None:
        """Turn a closed trimmed run into a window, or count why it is rejected."""
        g = self._geom
        if piece.last - piece.first + 1 < g.required:
            return  # already counted as a short piece when its quiet run closed
        s = piece.sums
        n = s[0]
        rejected = self.report.rejected
        span = (piece.t_first - self._t0, piece.t_last - self._t0)
        if n < 2:
            rejected["invalid_status"] += 1
            self.report._add_stretches(*span, "invalid_status")
            return
        d_g, d_a = s[1:4] / n, s[7:10] / n
        gyro = piece.g_ref + d_g
        limit = self.config.gyro_rate_max
        if limit is not None and float(np.linalg.norm(gyro - self._gyro_ref)) > limit:
            rejected["rotating"] += 1
            self.report._add_stretches(*span, "rotating")
            return
        var_g = np.maximum(s[4:7] - s[1:4] * d_g, 0.0) / (n - 1)
        var_a = np.maximum(s[10:13] - s[7:10] * d_a, 0.0) / (n - 1)
        kept = piece.last - piece.first + 1
        allan_sq, allan_terms = _allan_sums(piece.blocks, g.block)
        nt, st, stt, sv, stv = s[13:18]
        temp, rate = math.nan, math.nan
        if nt > 0:
            temp = sv / nt + self._temp_ref
            den = nt * stt - st * st
            if nt >= 2 and den > 0:
                rate = (nt * stv - st * sv) / den * 3600.0  # degC/s -> degC/h
        t0 = self._t0
        std = np.sqrt(np.concatenate((var_g, var_a)))
        sem = (
            allan_window_sem(int(n), std, allan_sq, allan_terms, g.block) if self._own_sem else None
        )
        self._out.append(
            Window(
                start_s=piece.t_first - t0,
                end_s=piece.t_last - t0,
                start_index=piece.first,
                end_index=piece.last,
                samples=int(n),
                gyro=gyro,
                accel=piece.a_ref + d_a,
                gyro_std=std[:3],
                accel_std=std[3:],
                temperature_c=float(temp),
                temperature_rate_c_per_h=float(rate),
                frames_lost=int(s[19]),
                frames_invalid=int(s[18]),
                accel_mvar=float(s[20] / kept),
                gyro_mvar=float(s[21] / kept),
                block_frames=g.block,
                allan_sq=allan_sq,
                allan_terms=allan_terms,
                gyro_sem=np.full(3, np.nan) if sem is None else sem[:3],  # its own samples
                accel_sem=np.full(3, np.nan) if sem is None else sem[3:],
            )
        )

        self.report.windows_kept += 1


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
