"""The hull detector's segmentation: the recording as blocks, each still, turning, accelerating or
faulty (step 1 of :mod:`recal.detect.hull`), from parabolic-weighted moving averages of the rate
and specific force judged against Earth's rate, gravity and the waves' residual."""

from __future__ import annotations

import math

import numpy as np

from recal.detect.hull_config import LONGEST_WAVE_S, HullConfig
from recal.detect.rest import RestReference


# ---- the block series ----------------------------------------------------------------------
def parabolic_kernel(n: int) -> np.ndarray:
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
    kern = parabolic_kernel(L)
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
