"""The drift test's threshold by simulation: the null model of the whitened windows is known
exactly, so the 1 - q quantile of max_n T_n is simulated for *these* windows (docs/drift.md,
"Threshold")."""

from __future__ import annotations

import numpy as np

from recal.diagnose.drift_glr import scan

#: Windows the threshold's null simulation covers at most (:func:`null_threshold`).
NULL_WINDOWS = 120
#: Exceedances of the threshold the null simulation expects at least, and its run limits.
NULL_EXCEEDANCES = 50
NULL_MIN_RUNS = 1000
NULL_MAX_RUNS = 20000
NULL_BATCH = 1000


def null_threshold(
    C: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    seen: np.ndarray,
    bound: float,
    *,
    false_alarm_windows: float,
    lookback: int,
    seed: int,
) -> tuple[float, int]:
    """The threshold at the configured false-alarm rate for these windows, and the simulated
    runs it took (0: the union bound ``bound`` was used).

    Under no change the whitened windows are w = e + C Lp eta (e, eta standard normal: the
    window noise and the coefficients' own error). One false alarm per N = false_alarm_windows
    windows means, over the first L = min(M, NULL_WINDOWS) windows, P(max_{n<L} T_n > h) =
    q = 1 - exp(-L / N): h is the 1 - q quantile of max_n T_n over simulated null sequences of
    exactly these windows (fixed seed: the same input gives the same threshold). Never above
    the union bound; the bound itself when q is too small to simulate (fewer than
    NULL_EXCEEDANCES exceedances expected in NULL_MAX_RUNS runs)."""
    M = C.shape[0]
    L = min(M, NULL_WINDOWS)
    if L == 0:
        return bound, 0
    q = -np.expm1(-L / false_alarm_windows)
    runs = int(np.ceil(NULL_EXCEEDANCES / q))
    if runs > NULL_MAX_RUNS:
        return bound, 0
    runs = max(runs, NULL_MIN_RUNS)
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(seed)
    dF = F[1 : L + 1] - F[:L]  # (L, D, D) per-window information
    # small products: BLAS threads only contend (4x slower on a loaded 2-core machine)
    with threadpool_limits(1, user_api="blas"):
        maxima = _null_maxima(C[:L], dF, F[: L + 1], Lp, seen, lookback, runs, rng)
    h = float(np.quantile(maxima, 1.0 - q))
    return min(h, bound), runs


def _null_maxima(
    C: np.ndarray,
    dF: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    seen: np.ndarray,
    lookback: int,
    runs: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """max_n T_n of ``runs`` simulated null sequences of the windows C (L, 3, D)."""
    L, D = C.shape[0], C.shape[2]
    maxima = []
    for start in range(0, runs, NULL_BATCH):
        P = min(NULL_BATCH, runs - start)
        e = rng.standard_normal((P, L, 3))
        eta = rng.standard_normal((P, Lp.shape[1])) @ Lp.T  # (P, D) coefficient errors
        u = np.einsum("mid,pmi->pmd", C, e) + np.einsum("mde,pe->pmd", dF, eta)
        S = np.concatenate([np.zeros((P, 1, D)), np.cumsum(u, axis=1)], axis=1)
        maxima.append(scan(S, F, Lp, seen, lookback, False)[0].max(axis=1))
    return np.concatenate(maxima)
