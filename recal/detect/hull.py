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
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from recal.detect.creep import MAX_CREEP_DPH, correct_rate, heading_rate, horizontal_loss
from recal.detect.rest import REST_REASONS, RestReference
from recal.detect.window_sem import weighted_mean_sem
from recal.detect.windows import Window
from recal.errors import RecalInputError

_DPH_TO_RAD_S = math.radians(1.0) / 3600.0
#: Longest wave period the segmentation allows for (s): roll of a large hull at anchor.
LONGEST_WAVE_S = 20.0
#: The motion's residual in a window's slope is 12 A_rms / (w T^2) averaged over the phase at
#: which the window starts; its largest value over the phase is sqrt(2) times that.
_PHASE = math.sqrt(2.0)
#: The share of the coning correction a window's rate sigma carries (what the second-order
#: correction leaves was 1-1.4 % of it on simulated seas of 1 and 3 degrees).
CONING_RESIDUAL = 0.03


@dataclass(frozen=True)
class HullConfig:
    """Settings of the hull detector; times in s, angles in deg, lengths in m."""

    block_s: float = 0.5
    turn_window_s: float = 60.0
    max_swing_deg: float = 1.0
    trim_s: float = 30.0
    min_window_s: float = 120.0
    max_window_s: float = 900.0
    lever_arm_max_m: float = 10.0
    max_gap_frames: int = 5
    #: the largest heading creep or anchor swing (deg/h) a window keeps where the ship's heading
    #: is unknown (recal.detect.creep): its vertical rate is then no measurement
    max_creep_dph: float = MAX_CREEP_DPH

    def __post_init__(self) -> None:
        for name in ("block_s", "turn_window_s", "min_window_s", "max_window_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise RecalInputError(f"hull detector {name} must be positive, not {v}")
        if self.min_window_s > self.max_window_s:
            raise RecalInputError("hull detector min_window_s exceeds max_window_s")
        if self.turn_window_s < 2 * LONGEST_WAVE_S:
            raise RecalInputError(
                f"turn_window_s {self.turn_window_s:g} s must span at least two of the longest "
                f"wave periods ({2 * LONGEST_WAVE_S:g} s)"
            )


@dataclass
class HullReport:
    """What the hull detector saw: blocks by state, windows kept and rejected by reason."""

    frames: int = 0
    sample_rate_hz: float | None = None
    blocks: int = 0
    blocks_turning: int = 0
    blocks_accelerating: int = 0
    blocks_fault: int = 0
    rejected: Counter = field(default_factory=Counter)
    rejected_stretches: list[tuple[float, float, str]] = field(default_factory=list)
    kept: int = 0

    def summary_lines(self) -> list[str]:
        rej = ", ".join(f"{r} {self.rejected.get(r, 0)}" for r in ("too_short", *REST_REASONS))
        lines = [
            f"hull detector: {self.kept} window(s) kept; rejected: {rej}",
            f"blocks: {self.blocks} ({self.blocks_turning} turning, {self.blocks_accelerating} "
            f"accelerating, {self.blocks_fault} with faults)",
        ]
        for a, b, why in self.rejected_stretches[:20]:
            lines.append(f"  {a:.1f}-{b:.1f} s ({b - a:.1f} s): {why}")
        return lines


@dataclass(frozen=True)
class HullWindow:
    """A quasi-static window and what its estimate rests on (the per-axis motion terms)."""

    window: Window
    gyro_motion_sem: np.ndarray  # (3,) output units: the waves' residual in the slope
    accel_motion_sem: np.ndarray  # (3,) output units: residual, lever arm, 2nd-order correction
    tilt_rms_deg: float  # RMS of the attitude oscillation about the mean, deg
    period_s: float  # effective period of that oscillation, s


# ---- the block series ----------------------------------------------------------------------
def _parabolic_kernel(n: int) -> np.ndarray:
    """Weights proportional to u (1 - u) over n points (sum 1): the OLS slope of an integral."""
    u = (np.arange(n) + 0.5) / n
    w = u * (1.0 - u)
    return w / w.sum()


def _moving(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Centred weighted moving average of each column; NaN where the kernel leaves the data."""
    n, k = len(x), len(kernel)
    out = np.full(x.shape, np.nan)
    if n < k:
        return out
    h = k // 2
    for j in range(x.shape[1]):  # a loop over 3 axes; np.convolve is vectorised over samples
        out[h : h + n - k + 1, j] = np.convolve(x[:, j], kernel[::-1], mode="valid")
    return out


def block_states(
    gyro: np.ndarray, accel: np.ndarray, ok: np.ndarray, rate_hz: float, ref: RestReference,
    cfg: HullConfig,
) -> tuple[np.ndarray, int]:  # fmt: skip
    """State per block (0 still, 1 turning, 2 accelerating, 3 fault) and frames per block."""
    B = max(1, round(cfg.block_s * rate_hz))
    nb = len(gyro) // B
    if nb == 0:
        return np.zeros(0, dtype=np.int8), B
    g = gyro[: nb * B].reshape(nb, B, 3)
    a = accel[: nb * B].reshape(nb, B, 3)
    okb = ok[: nb * B].reshape(nb, B)
    cnt = okb.sum(axis=1)
    fault = cnt < (B + 1) // 2
    safe = np.maximum(cnt, 1)[:, None]
    gm = np.where(okb[..., None], g, 0.0).sum(axis=1) / safe
    am = np.where(okb[..., None], a, 0.0).sum(axis=1) / safe
    # fill faulty blocks from their neighbours so the moving averages stay defined
    if fault.any() and not fault.all():
        good = np.flatnonzero(~fault)
        for x in (gm, am):
            for j in range(3):
                x[fault, j] = np.interp(np.flatnonzero(fault), good, x[good, j])
    L = max(3, round(cfg.turn_window_s / cfg.block_s) | 1)
    kern = _parabolic_kernel(L)
    w = ref.rate_dph(gm)
    f = ref.force_g(am)
    W = _moving(w, kern)
    F = _moving(f, kern)
    # the waves' residual in a parabolic average: 12 rho / (w^2 L^2) for an oscillation of RMS rho
    # at angular frequency w. w is measured: the RMS of the oscillation's rate of change over its
    # RMS (divided by 1.5 for safety), never slower than the longest wave period. Taking that
    # worst case everywhere made rough seas hide turns (3 degrees of roll: 600 deg/h of bound).
    span = L * cfg.block_s
    om_min = 2.0 * math.pi / LONGEST_WAVE_S

    def residual(x: np.ndarray, X: np.ndarray) -> np.ndarray:
        rho = np.sqrt(np.maximum(_moving(x**2, kern) - X**2, 0.0).sum(axis=1))
        d = np.vstack([np.diff(x, axis=0), np.zeros((1, 3))]) / cfg.block_s
        D = _moving(d, kern)
        rho_d = np.sqrt(np.maximum(_moving(d**2, kern) - D**2, 0.0).sum(axis=1))
        om = np.maximum(rho_d / np.maximum(rho, 1e-300) / 1.5, om_min)
        return 12.0 * rho / (om * span) ** 2

    wave_w = residual(w, W)
    wave_f = residual(f, F)
    swing_dph = 2.0 * cfg.max_swing_deg / span * 3600.0
    Wn = np.linalg.norm(W, axis=1)
    Fn = np.linalg.norm(F, axis=1)
    turning = Wn - ref.earth_rate_dph > ref.rate_tolerance_dph() + 3.0 * wave_w + swing_dph
    accel_bad = np.abs(Fn - ref.gravity_g) > ref.force_tolerance_g() + 3.0 * wave_f
    state = np.zeros(nb, dtype=np.int8)
    undefined = ~np.isfinite(Wn)
    state[accel_bad] = 2
    state[turning] = 1
    state[undefined] = 3  # the first and last half window: no average to judge by
    state[fault] = 3
    return state, B


# ---- one window's estimate --------------------------------------------------------------------
def estimate_window(
    t: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    ref: RestReference,
    cfg: HullConfig,
    heading_deg: np.ndarray | None = None,
) -> tuple:
    """Rate and specific force of one quasi-static window, output units, and their 1-sigma.

    Returns gyro mean (3,), accel mean (3,), gyro sem (3,), accel sem (3,), the tilt RMS (rad),
    the oscillation's effective angular frequency (rad/s), the motion's parts of the gyro and
    accel sems (3,) each, and the heading creep (:mod:`recal.detect.creep`): its rate (deg/h,
    clockwise; NaN unknown) and whether the vertical rate is a measurement (the ship's heading
    ``heading_deg`` (n,), deg, NaN where unknown, gave the creep). ``t`` (n,) s; samples valid.
    """
    n = len(t)
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    T = n * dt
    w = _parabolic_kernel(n)  # weights of the OLS slope of the integral, sum 1
    # the attitude oscillation about the window's mean attitude, rad: the rotation vector that
    # the oscillation's own rate integrates (mid-sample, coning-corrected to second order, so
    # roll and pitch out of phase do not make its vertical part wander), less its least-squares
    # line, about its weighted mean. The oscillation's own rate is the rate less its weighted
    # mean and less the turning of Earth's rate in the rocking body (-delta x w; the rocking
    # loss M below counts that part): left in, its integral crossed with the roll rate doubles
    # the second-order terms.
    rate = ref.rate_dph(gyro) * _DPH_TO_RAD_S
    w_first = w @ rate
    tc = (np.arange(n) + 0.5) * dt

    def attitude(r: np.ndarray, coned: bool) -> np.ndarray:
        d = (np.cumsum(r, axis=0) - 0.5 * r) * dt
        if coned:
            d += 0.5 * np.cumsum(np.cross(d, r), axis=0) * dt
        line = np.polyfit(tc, d, 1)  # (2, 3): slope, intercept
        d -= line[1] + np.outer(tc, line[0])
        return d - w @ d

    rate_res = rate - w_first
    rate_res = rate_res + np.cross(attitude(rate_res, False), w_first)  # rad/s
    delta = attitude(rate_res, True)
    # the rocking loss of a mean over an oscillating attitude: mean(C^T v) = M v for any vector
    # fixed in space (Earth's rate, gravity), v in the mean attitude, M = I + (S - tr S I) / 2
    S = (delta * w[:, None]).T @ delta
    M = np.eye(3) + 0.5 * (S - np.trace(S) * np.eye(3))
    # rate: the parabolic-weighted mean of the body rate (the OLS slope of its integral: it keeps
    # 12 A / (w T^2) of a wave), less the rate that roll and pitch out of phase rectify (coning:
    # the body turns about the third axis on average while its attitude only oscillates,
    # mean rate = -1/2 mean(delta x delta'); 0.4 deg/h at 1 degree of roll, 3.6 at 3), then the
    # rocking loss. The rate and the specific force's mean share one frame, the weighted mean
    # attitude, so their dot product is right to first order in the tilt. (The slope of the
    # rotation vector taken to that frame instead put the rate half a tilt off the force's
    # frame: a dot-product error of up to 0.13 deg/h g at 1 degree of roll, which no sem carried.)
    coning = 0.5 * (w @ np.cross(delta, rate_res))
    w0 = np.linalg.solve(M, w_first + coning)
    gyro_mean = (w0 / _DPH_TO_RAD_S + ref.gyro_bias_dph) * ref.gyro_scale
    # specific force: the weighted mean, then the same rocking loss
    f = ref.force_g(accel)
    f_bar = w @ f
    f0 = np.linalg.solve(M, f_bar)
    f0, lever_sem = _lever_arm(f, f0, delta, rate_res, dt, cfg)
    accel_mean = (f0 + ref.accel_bias_g) * ref.accel_scale
    # heading creep: measured from the ship's heading, else estimated from the vertical excess
    # for the horizontal averaging loss only (the vertical rate is then no measurement)
    up = f0 / max(float(np.linalg.norm(f0)), 1e-300)
    w0_dph = w0 / _DPH_TO_RAD_S
    creep, creep_sd = heading_rate(tc, heading_deg) if heading_deg is not None else (
        math.nan, math.nan)  # fmt: skip
    vertical_known = math.isfinite(creep)
    if not vertical_known:
        v_e, _ = ref.earth_rate_parts_dph()
        creep = v_e - float(w0_dph @ up) if math.isfinite(v_e) else math.nan
    loss = horizontal_loss(tc, w, creep)
    w0_dph = correct_rate(w0_dph, up, creep, loss, vertical_known)
    gyro_mean = (w0_dph + ref.gyro_bias_dph) * ref.gyro_scale
    # the sensor's noise through the weights: its long-run variance (a filtered FOG's samples
    # are correlated, so not from second differences) times sum w^2 (recal.detect.window_sem)
    sw2 = float(w @ w)

    def white(x: np.ndarray) -> np.ndarray:
        return weighted_mean_sem(x, sw2, dt)

    gyro_white = white(gyro)
    accel_white = white(accel)
    # the motion's residual: 12 A_rms / (w T^2) per axis and per band. Waves (seconds) and a
    # berth's yaw swing (minutes) are different motions on the same axes: split the oscillation
    # at the longest wave period, so the slow part is not judged at the waves' frequency.
    slowest = 2.0 * math.pi / T  # nothing slower than the window shows
    gyro_motion = _band_residual(delta, dt, T, slowest, power=1) / _DPH_TO_RAD_S
    # what the second-order coning term leaves: about 1.2 % of it on simulated seas of 1 and 3
    # degrees (noise free); carried at CONING_RESIDUAL of it
    gyro_motion = np.hypot(gyro_motion, CONING_RESIDUAL * np.abs(coning) / _DPH_TO_RAD_S)
    gyro_motion *= np.abs(ref.gyro_scale)
    a_all = np.sqrt(np.mean(delta**2, axis=0))
    tilt = float(np.sqrt(np.sum(a_all**2)))
    r_rms = np.sqrt(np.mean(rate_res**2, axis=0))
    om = float(np.sqrt(np.sum(r_rms**2)) / tilt) if tilt > 0 else slowest
    om = max(om, slowest)
    # the specific force's oscillation, its white noise smoothed away first (half a second,
    # which waves of 4 s and more pass): the parabolic mean keeps 12 a / (w^2 T^2) of it
    m_short = max(1, round(0.5 / dt))
    f_osc = _box_smooth(_box_smooth(f - f_bar, m_short), m_short)
    accel_resid = _band_residual(f_osc, dt, T, slowest, power=2)
    second = 0.1 * np.abs(f0 - f_bar)
    accel_motion = np.sqrt(accel_resid**2 + lever_sem**2 + second**2) * np.abs(ref.accel_scale)
    if vertical_known:  # the measured creep's 1-sigma, along up
        gyro_motion = np.hypot(gyro_motion, np.abs(up) * creep_sd * np.abs(ref.gyro_scale))
    gyro_sem = np.sqrt(gyro_white**2 + gyro_motion**2)
    accel_sem = np.sqrt(accel_white**2 + accel_motion**2)
    return (gyro_mean, accel_mean, gyro_sem, accel_sem, tilt, om, gyro_motion, accel_motion,
            creep, vertical_known)  # fmt: skip


# ---- the whole recording -----------------------------------------------------------------------
def _lever_arm(
    f: np.ndarray, f0: np.ndarray, delta: np.ndarray, osc: np.ndarray, dt: float, cfg: HullConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The specific force without the lever arm's centripetal mean, and that correction's 1-sigma.

    The IMU sits r from the hull's centre of rotation, so it also senses alpha x r (zero mean)
    and w x (w x r), whose mean (E[w w^T] - E|w|^2 I) r is not zero: 48 ug at r = 5 m, 1 degree
    of roll at 8 s. r is estimated from the tangential part, alpha x r, in the two channels across
    gravity (heave acts along it): f - (f0 - delta x f0) regressed on [alpha]x, alpha from the
    smoothed gyro oscillation. The correction's sigma comes from the regression; where the fit
    cannot pin r down (too little motion: its sigma exceeds the bound's), or finds it beyond
    3 x ``lever_arm_max_m``, no
    correction is made and the sigma is the centripetal mean of a lever arm of
    ``lever_arm_max_m`` (what the simple bound gives). f, f0 in g; osc in rad/s.
    """
    g0 = 9.80665
    n = len(f)
    W = (osc.T @ osc) / max(n, 1)  # E[w w^T], rad^2/s^2
    J = (W - np.trace(W) * np.eye(3)) / g0  # centripetal mean per metre of r, g/m
    bound = np.full(3, float(np.trace(W)) * cfg.lever_arm_max_m / g0 / math.sqrt(3.0))
    if n < 8:
        return f0, bound
    m = max(1, round(0.5 / dt))
    smooth = _box_smooth(_box_smooth(osc, m), m)
    alpha = np.gradient(smooth, dt, axis=0)
    u = f0 / max(float(np.linalg.norm(f0)), 1e-12)
    P = np.eye(3) - np.outer(u, u)
    e = (f - (f0 - np.cross(delta, f0))) @ P  # across gravity, g
    # alpha x r = S(alpha) r, with S the cross-product matrix
    S = np.zeros((n, 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -alpha[:, 2], alpha[:, 1], -alpha[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = alpha[:, 2], -alpha[:, 1], alpha[:, 0]
    A = np.einsum("ij,njk->nik", P, S).reshape(-1, 3) / g0
    A -= np.tile(A.reshape(n, 3, 3).mean(axis=0), (n, 1))
    y = (e - e.mean(axis=0)).reshape(-1)
    AtA = A.T @ A
    if not np.all(np.isfinite(AtA)) or np.linalg.cond(AtA) > 1e12 or np.trace(AtA) == 0:
        return f0, bound
    r = np.linalg.solve(AtA, A.T @ y)
    dof = max(len(y) - 3, 1)
    # the samples' noise is not white at the smoothing's scale: count one sample per smoothing
    s2 = float(np.sum((y - A @ r) ** 2)) / dof * m
    cov_r = s2 * np.linalg.inv(AtA)
    if not np.all(np.isfinite(r)) or np.linalg.norm(r) > 3.0 * cfg.lever_arm_max_m:
        return f0, bound
    c = J @ r
    sem = np.sqrt(np.maximum(np.diag(J @ cov_r @ J.T), 0.0))
    if np.any(sem > bound):  # the fit knows less than the bound: keep the bound, no correction
        return f0, bound
    return f0 - c, sem


def _band_residual(x: np.ndarray, dt: float, T: float, slowest: float, power: int) -> np.ndarray:
    """What a parabolic-weighted mean over T keeps of an oscillation x (n, 3), per axis: the
    largest over its phase, sqrt(2) x 12 a_rms / (w^power T^2), for the waves (below the longest
    wave period) and the slow part (above it) apart, in quadrature. power 1: x is an angle and the
    mean is of its rate (the gyro); power 2: x itself is averaged (the accelerometer)."""
    # three passes of a box of one wave period: the waves leak about 1e-3 of their amplitude
    # into the slow part (one pass leaks 10 %, enough to fake the slow part's frequency)
    m = max(1, round(LONGEST_WAVE_S / dt))
    slow = _box_smooth(_box_smooth(_box_smooth(x, m), m), m)
    out = np.zeros(x.shape[1])
    for part in (x - slow, slow):
        a_rms = np.sqrt(np.mean(part**2, axis=0))
        d = np.diff(part, axis=0) / dt if len(part) > 1 else np.zeros((1, x.shape[1]))
        r_rms = np.sqrt(np.mean(d**2, axis=0))
        om = np.maximum(np.where(a_rms > 0, r_rms / np.maximum(a_rms, 1e-300), slowest), slowest)
        out += (_PHASE * 12.0 * a_rms / (om**power * T**2)) ** 2
    return np.sqrt(out)


def _box_smooth(x: np.ndarray, m: int) -> np.ndarray:
    """Centred moving average of each column over m samples (shorter at the ends)."""
    n = len(x)
    if m <= 1 or n < 2:
        return x.copy()
    c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    lo = np.clip(np.arange(n) - m // 2, 0, n)
    hi = np.clip(np.arange(n) - m // 2 + m, 0, n)
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


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
