"""The baseline the drift test is measured against (benchmarks/bench_drift.py): a plain two-sided
CUSUM per invariant that ignores the coefficients' own uncertainty. A benchmark's tool, not
shipped (tests import it from benchmarks/ as ``drift_cusum``)."""

from __future__ import annotations

import numpy as np

from recal.diagnose.drift import DriftConfig, DriftInputs, DriftResult

#: Plain CUSUM baseline (:func:`plain_cusum`): reference value k in sigma of one window.
PLAIN_CUSUM_K = 0.5


def plain_cusum(inputs: DriftInputs, config: DriftConfig | None = None) -> DriftResult:
    """The baseline the issue measures against: a two-sided CUSUM per invariant on the residuals
    whitened by each window's own noise alone (the coefficients' uncertainty ignored), reference
    value k = 0.5 sigma, threshold from Siegmund's approximation of the in-control run length,
    ARL0 = (exp(2k(h + 1.166)) - 2k(h + 1.166) - 1) / (2 k^2), set to 6 x false_alarm_windows
    (six one-sided CUSUMs)."""
    from scipy.optimize import brentq

    config = config or DriftConfig()
    k = PLAIN_CUSUM_K
    sd = np.sqrt(np.einsum("mii->mi", inputs.noise_cov))
    y = np.where(inputs.active, inputs.residual / sd, 0.0)
    target = 6.0 * config.false_alarm_windows

    def arl(hh: float) -> float:
        b = 2 * k * (hh + 1.166)
        return (np.exp(b) - b - 1) / (2 * k * k) - target

    h = float(brentq(arl, 0.0, 100.0))
    up = np.zeros(3)
    lo = np.zeros(3)
    stat = np.zeros(inputs.M)
    alarm = None
    for n in range(inputs.M):
        on = inputs.active[n]
        up = np.where(on, np.maximum(0.0, up + y[n] - k), up)
        lo = np.where(on, np.maximum(0.0, lo - y[n] - k), lo)
        stat[n] = max(up.max(), lo.max())
        if alarm is None and stat[n] > h:
            alarm = n
    zeros = np.zeros(inputs.M)
    return DriftResult(stat, h, alarm, zeros.astype(int), zeros.astype(int), zeros, zeros,
                       directions=3, config=config)  # fmt: skip
