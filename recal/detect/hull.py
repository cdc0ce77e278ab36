"""Quasi-static windows on a moving hull: a berth where the vessel rolls, pitches, heaves and
swings, and turns now and then (docs/static.md#a-hull-that-is-never-still).

A moored hull is never still, so a moving-variance test finds only the lulls between wave crests
(1 to 9 s "windows" whose means carry the wave's phase). Here stillness is judged on the
time scale of the waves and by physics:

1. **Segmentation.** The recording is cut into blocks of ``block_s``. A block is *turning* when
   the rate averaged over ``turn_window_s`` around it (a parabolic weight, which passes waves
   about (P / L)^2 times less than a plain mean) exceeds Earth's rate by more than the unit's
   plausible coefficient error, the waves' residual in that average, and the largest heading
   change a berth swing makes (``max_swing_deg`` twice over ``turn_window_s``): a turn of 0.1
   deg/s and more (``shared/spec/vessel.md``) always is. A block is *accelerating* when the
   averaged specific force is not gravity. Runs of the other blocks, trimmed by ``trim_s`` (half
   the turn window: a slow turn's first seconds move the average too little to be seen), cut
   into pieces of at most ``max_window_s``, and at least ``min_window_s`` long, are the
   candidate windows.
2. **The window's rate** is the parabolic-weighted mean of the body rate, which is the
   least-squares slope of the attitude the gyro integrates, not the plain mean. For periodic
   motion of angular frequency w and angle A, a plain mean keeps up to 2 A / T of the net
   attitude change over T (12 deg/h at 1 degree of roll over 10 minutes: as large as Earth's
   rate); the slope keeps about 12 A / (w T^2) (0.15 deg/h). It lives in the window's weighted
   mean attitude, the frame of the specific force's mean below, and is corrected for the same
   rocking loss (Earth's rate, like gravity, is fixed in space).
3. **The window's specific force** is the same parabolic-weighted mean of the accelerometer
   outputs, corrected for the second-order loss of a rocking mean (its norm is low by g A^2 / 4,
   76 ug at 1 degree): the gyro's own attitude oscillation gives that correction.
4. **Uncertainty.** Each mean carries the sensor's noise through the weights (its long-run
   variance from block differences of the samples, which a FOG's own low-pass cannot shrink and
   the waves do not reach: :mod:`recal.detect.window_sem`) plus the motion's residual
   (12 A_rms / (w T^2) per axis, from the window's own oscillation amplitude and frequency), plus,
   for the accelerometer, the centripetal acceleration of an unknown lever arm up to
   ``lever_arm_max_m`` and a tenth of the second-order correction. A wave-contaminated mean never
   gets a still window's sigma.
5. **Physics.** The corrected means go through the rest check (:mod:`recal.detect.rest`) with
   those standard errors; a window that fails is rejected with its reason.
6. **Heading creep and anchor swing** (:mod:`recal.detect.creep`): measured from the ship's
   heading where it is given and taken out of the vertical rate; otherwise the window's vertical
   rate is no measurement (``gyro_vertical`` False), allowed up to ``max_creep_dph`` by the rest
   check and left out by the fit. Either way the horizontal rate's averaging loss is divided out.

Everything works on sample arrays (:func:`detect_hull`) or incrementally (:class:`HullDetector`,
which buffers at most ``max_window_s`` plus the look-ahead). Pure numpy.

The parts live beside it: the settings and results (:mod:`recal.detect.hull_config`:
:class:`HullConfig`, :class:`HullReport`, :class:`HullWindow`, importable from here too), the
segmentation (:mod:`recal.detect.hull_blocks`, step 1) and one window's estimate
(:mod:`recal.detect.hull_window`, steps 2 to 4 and 6: :func:`estimate_window`, importable from
here too).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from recal.detect.hull_blocks import block_states
from recal.detect.hull_config import HullConfig, HullReport, HullWindow
from recal.detect.hull_window import estimate_window  # docs/measurements.md names it here
from recal.detect.rest import RestReference
from recal.detect.windows import Window
from recal.errors import RecalInputError


# ---- the whole recording -----------------------------------------------------------------------
def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of True."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def detect_hull(
    time_s: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    ref: RestReference,
    cfg: HullConfig | None = None,
    temperature_c: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    rate_hz: float | None = None,
    heading_deg: np.ndarray | None = None,
) -> tuple[list[HullWindow], HullReport]:
    """Quasi-static windows of a recording (arrays of frames, output units).

    ``heading_deg`` (n,): the ship's true heading at each frame (``[nav]``, NaN where unknown):
    where a window has it, its heading creep is measured and its vertical rate kept
    (:mod:`recal.detect.creep`); elsewhere the vertical rate is no measurement."""
    cfg = cfg or HullConfig()
    time_s = np.asarray(time_s, float)
    n = len(time_s)
    gyro = np.asarray(gyro, float)
    accel = np.asarray(accel, float)
    if gyro.shape != (n, 3) or accel.shape != (n, 3):
        raise RecalInputError("the hull detector needs both triads, (n, 3) each")
    if rate_hz is None:
        if n < 2:
            raise RecalInputError("too few frames for the hull detector")
        rate_hz = 1.0 / float(np.median(np.diff(time_s)))
    ok = np.ones(n, dtype=bool) if valid is None else np.asarray(valid, bool)
    ok &= np.isfinite(gyro).all(axis=1) & np.isfinite(accel).all(axis=1)
    report = HullReport(frames=n, sample_rate_hz=float(rate_hz))
    state, B = block_states(gyro, accel, ok, rate_hz, ref, cfg)
    report.blocks = len(state)
    report.blocks_turning = int(np.sum(state == 1))
    report.blocks_accelerating = int(np.sum(state == 2))
    report.blocks_fault = int(np.sum(state == 3))
    trim = round(cfg.trim_s * rate_hz)
    min_n = round(cfg.min_window_s * rate_hz)
    max_n = round(cfg.max_window_s * rate_hz)
    pieces: list[tuple[int, int]] = []
    for b0, b1 in _runs(state == 0):  # a loop over runs (tens per day), not samples
        a, b = b0 * B + trim, b1 * B - trim
        if b - a < min_n:
            if b - a > 0:
                report.rejected["too_short"] += 1
                report.rejected_stretches.append((time_s[a], time_s[b - 1], "too short"))
            continue
        k = max(1, math.ceil((b - a) / max_n))
        edges = np.linspace(a, b, k + 1).round().astype(int)
        pieces.extend(zip(edges[:-1], edges[1:], strict=True))
    out: list[HullWindow] = []
    cand = []
    for a, b in pieces:  # a loop over windows; each estimate is vectorised over its samples
        sel = np.flatnonzero(ok[a:b]) + a
        psi = None if heading_deg is None else np.asarray(heading_deg, float)[sel]
        est = estimate_window(time_s[sel], gyro[sel], accel[sel], ref, cfg, psi)
        cand.append((a, b, sel, est))
    if cand:
        g = np.array([c[3][0] for c in cand])
        f = np.array([c[3][1] for c in cand])
        gs = np.array([c[3][2] for c in cand])
        fs = np.array([c[3][3] for c in cand])
        free = np.array([not c[3][9] for c in cand])
        reasons = ref.judge(
            g, f, gs, fs, vertical_allowance_dph=np.where(free, cfg.max_creep_dph, 0.0)
        )
    for (a, b, sel, est), why in zip(cand, reasons if cand else [], strict=True):
        gm, fm, gsem, fsem, tilt, om, gmot, fmot, creep, vertical_known = est
        if why:
            report.rejected[why] += 1
            report.rejected_stretches.append((time_s[a], time_s[b - 1], str(why)))
            continue
        temp = (
            float(np.nanmean(temperature_c[sel]))
            if temperature_c is not None and np.isfinite(temperature_c[sel]).any()
            else math.nan
        )
        rate_c = (
            _slope_per_h(time_s[sel], temperature_c[sel]) if temperature_c is not None else math.nan
        )
        win = Window(
            start_s=float(time_s[a] - time_s[0]),
            end_s=float(time_s[b - 1] - time_s[0]),
            start_index=int(a),
            end_index=int(b - 1),
            samples=int(len(sel)),
            gyro=gm,
            accel=fm,
            gyro_std=gyro[sel].std(axis=0, ddof=1),
            accel_std=accel[sel].std(axis=0, ddof=1),
            temperature_c=temp,
            temperature_rate_c_per_h=rate_c,
            frames_lost=0,
            frames_invalid=int((b - a) - len(sel)),
            gyro_sem=gsem,
            accel_sem=fsem,
            quasi_static=True,
            gyro_vertical=bool(vertical_known),
            creep_dph=float(creep),
        )
        out.append(HullWindow(win, gmot, fmot, math.degrees(tilt), 2.0 * math.pi / om))
    report.kept = len(out)
    return out, report


def _slope_per_h(t: np.ndarray, y: np.ndarray) -> float:
    m = np.isfinite(y)
    if m.sum() < 2:
        return math.nan
    tt, yy = t[m] - t[m].mean(), y[m] - y[m].mean()
    d = float(tt @ tt)
    return float(tt @ yy / d) * 3600.0 if d > 0 else math.nan


class HullDetector:
    """The hull detector fed frame chunks as they arrive (the daemon's form of :func:`detect_hull`).

    It buffers frames until it holds ``max_window_s`` plus three turn windows, or the stream ends;
    then it runs :func:`detect_hull` on the buffer, emits the windows that end at least two turn
    windows before the buffer's end (the rest may still grow), and drops the frames it has
    decided, never those of a window still waiting nor the half turn window its first blocks are
    judged with. Memory is bounded by that buffer (18 min at the defaults). Window times and
    indices count from the first frame fed.
    """

    def __init__(self, ref: RestReference, cfg: HullConfig | None = None, rate_hz: float = 100.0):
        self.ref = ref
        self.cfg = cfg or HullConfig()
        self.rate_hz = float(rate_hz)
        self.report = HullReport(sample_rate_hz=self.rate_hz)
        self._chunks: list[tuple[np.ndarray, ...]] = []
        self._buffered = 0
        self._offset = 0  # global index of the buffer's first frame
        self._t0: float | None = None
        # a waiting window (at most max_window_s, ending in the last two turn windows) and the
        # half turn window before it fit, with room to spare: every decision drops frames
        span = self.cfg.max_window_s + 3.0 * self.cfg.turn_window_s + 4.0 * self.cfg.trim_s
        self._capacity = round(span * self.rate_hz)

    def feed(
        self,
        time_s: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        temperature_c: np.ndarray | None = None,
        valid: np.ndarray | None = None,
        heading_deg: np.ndarray | None = None,
    ) -> list[HullWindow]:
        """``heading_deg`` (n,): the ship's true heading per frame, NaN where unknown (as
        :func:`detect_hull`)."""
        n = len(time_s)
        if n == 0:
            return []
        if self._t0 is None:
            self._t0 = float(time_s[0])
        temp = np.full(n, np.nan) if temperature_c is None else np.asarray(temperature_c, float)
        ok = np.ones(n, dtype=bool) if valid is None else np.asarray(valid, bool)
        psi = np.full(n, np.nan) if heading_deg is None else np.asarray(heading_deg, float)
        self._chunks.append((np.asarray(time_s, float), np.asarray(gyro, float),
                             np.asarray(accel, float), temp, ok, psi))  # fmt: skip
        self._buffered += n
        self.report.frames += n
        out: list[HullWindow] = []
        while self._buffered >= self._capacity:
            out += self._decide(final=False)
        return out

    def flush(self) -> list[HullWindow]:
        """The end of the input: decide everything buffered."""
        return self._decide(final=True) if self._buffered else []

    def _decide(self, final: bool) -> list[HullWindow]:
        t, g, a, temp, ok, psi = (np.concatenate(x) for x in zip(*self._chunks, strict=True))
        wins, rep = detect_hull(t, g, a, self.ref, self.cfg, temp, ok, self.rate_hz,
                                psi if np.isfinite(psi).any() else None)  # fmt: skip
        horizon = len(t) if final else len(t) - round(2.0 * self.cfg.turn_window_s * self.rate_hz)
        emitted = [w for w in wins if w.window.end_index < horizon]
        if final:
            cut = len(t)
        elif emitted:
            cut = emitted[-1].window.end_index + 1
        else:
            cut = max(1, horizon - round(self.cfg.turn_window_s * self.rate_hz))
            # a window (or a quiet stretch too short so far) reaching past the horizon may
            # still grow: keep it whole, with the half turn window of blocks before its start
            # that its first block's average needs (cutting into it lost the window), on the
            # same block grid
            waiting = [w.window.start_index for w in wins if w.window.end_index >= horizon]
            waiting += [int(np.searchsorted(t, a0)) for a0, b0, why in rep.rejected_stretches
                        if why == "too short" and b0 >= t[horizon - 1]]  # fmt: skip
            if waiting:
                B = max(1, round(self.cfg.block_s * self.rate_hz))
                half = round((0.5 * self.cfg.turn_window_s + self.cfg.trim_s) * self.rate_hz)
                cut = max(1, min(cut, (min(waiting) - half - B) // B * B))
        # only what lies before the cut counts: the rest is judged again with more data
        for a0, b0, why in rep.rejected_stretches:
            if final or b0 < t[cut - 1]:
                key = "too_short" if why == "too short" else why
                self.report.rejected[key] += 1
                self.report.rejected_stretches.append((a0 - self._t0, b0 - self._t0, why))
        nb = cut // max(1, round(self.cfg.block_s * self.rate_hz))
        blocks = rep.blocks if final else min(rep.blocks, nb)
        self.report.blocks += blocks
        # block states of the decided part, in proportion (the undecided part is counted later)
        share = blocks / rep.blocks if rep.blocks else 0.0
        self.report.blocks_turning += round(rep.blocks_turning * share)
        self.report.blocks_accelerating += round(rep.blocks_accelerating * share)
        self.report.blocks_fault += round(rep.blocks_fault * share)
        shifted = []
        for hw in emitted:
            w = hw.window
            moved = _shift(w, self._offset, float(t[0]) - self._t0)
            shifted.append(HullWindow(moved, hw.gyro_motion_sem, hw.accel_motion_sem,
                                      hw.tilt_rms_deg, hw.period_s))  # fmt: skip
        self.report.kept += len(shifted)
        # keep the undecided tail
        keep = (t[cut:], g[cut:], a[cut:], temp[cut:], ok[cut:], psi[cut:])
        self._chunks = [keep] if len(keep[0]) else []
        self._buffered = len(keep[0])
        self._offset += cut
        return shifted


def _shift(w: Window, index_offset: int, time_offset: float) -> Window:
    return replace(
        w,
        start_s=w.start_s + time_offset,
        end_s=w.end_s + time_offset,
        start_index=w.start_index + index_offset,
        end_index=w.end_index + index_offset,
    )
