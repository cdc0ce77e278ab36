"""One quasi-static window's estimate on a moving hull (steps 2 to 4 and 6 of
:mod:`recal.detect.hull`): the parabolic-weighted rate and specific force, corrected for coning,
the rocking loss, the lever arm and heading creep, and their 1-sigma (the sensor's noise through
the weights plus the motion's residual)."""

from __future__ import annotations

import math

import numpy as np

from recal.detect.creep import correct_rate, heading_rate, horizontal_loss
from recal.detect.hull_blocks import parabolic_kernel
from recal.detect.hull_config import LONGEST_WAVE_S, HullConfig
from recal.detect.rest import RestReference
from recal.detect.window_sem import weighted_mean_sem

_DPH_TO_RAD_S = math.radians(1.0) / 3600.0
#: The motion's residual in a window's slope is 12 A_rms / (w T^2) averaged over the phase at
#: which the window starts; its largest value over the phase is sqrt(2) times that.
_PHASE = math.sqrt(2.0)
#: The share of the coning correction a window's rate sigma carries (what the second-order
#: correction leaves was 1-1.4 % of it on simulated seas of 1 and 3 degrees).
CONING_RESIDUAL = 0.03


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
    w = parabolic_kernel(n)  # weights of the OLS slope of the integral, sum 1
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
