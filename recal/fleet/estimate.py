"""The ageing rate of each coefficient of a model, by maximum likelihood.

The ageing law is a random walk: between two accepted versions ``dt`` months apart a
coefficient's true value changes by a zero-mean step of variance ``s**2 dt``, independent of the
past (no trend is assumed: a unit's history shows none that the fleet would share, and a
random walk is what a coefficient wandering with temperature cycles, shocks and fibre ageing
looks like over months). The observed change also carries both versions' measurement errors:

    Var(delta) = s**2 dt + sigma_1**2 + sigma_2**2

A naive standard deviation of the changes over sqrt(dt) would count the measurement errors as
ageing, and weigh a change over two weeks like one over two years. The estimate here maximises
the Gaussian likelihood of every change with its own ``dt`` and measurement variance, by Fisher
scoring on ``q = s**2 >= 0``, for all coefficients at once (arrays (changes, coefficients); no
loop over units or changes). Its 1-sigma is the inverse Fisher information, carried to ``s`` by
the delta method (floored where ``q`` is 0: the rate is then an upper bound, not a zero).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Fisher-scoring iterations (the log-likelihood in q is smooth and unimodal in practice; the
#: step stops changing well before this).
ITERATIONS = 60


class RateEstimate(NamedTuple):
    """Per coefficient: the random-walk rate (change 1-sigma after one month) and its 1-sigma,
    with the number of changes behind it."""

    rate: np.ndarray  # (P,)
    rate_sigma: np.ndarray  # (P,)
    changes: np.ndarray  # (P,) int


def random_walk_rate(delta: np.ndarray, months: np.ndarray, variance: np.ndarray) -> RateEstimate:
    """Maximum-likelihood rate ``s`` per column of ``delta`` (C, P): changes over ``months``
    (C,) with measurement variance ``variance`` (C, P) (sigma_1**2 + sigma_2**2). NaN entries
    (a coefficient held or absent in either version) are left out."""
    delta = np.asarray(delta, float)
    t = np.broadcast_to(np.asarray(months, float)[:, None], delta.shape)
    ok = np.isfinite(delta) & np.isfinite(variance) & (t > 0)
    w = ok.astype(float)
    d2 = np.where(ok, delta, 0.0) ** 2
    c = np.where(ok, variance, 1.0)
    t = np.where(ok, t, 0.0)
    n = w.sum(axis=0)
    # start: the moment estimate (excess squared change per month), kept positive
    q = np.maximum((w * (d2 - c)).sum(0) / np.maximum((w * t).sum(0), 1e-300), 0.0)
    q = np.maximum(q, 1e-3 * (w * c).sum(0) / np.maximum((w * t).sum(0), 1e-300))
    for _ in range(ITERATIONS):
        v = q * t + c
        score = 0.5 * (w * t * (d2 - v) / v**2).sum(0)
        info = 0.5 * (w * t**2 / v**2).sum(0)
        q = np.maximum(q + score / np.maximum(info, 1e-300), 0.0)
    v = q * t + c
    info = 0.5 * (w * t**2 / v**2).sum(0)
    return rate_of_variance(q, 1.0 / np.sqrt(np.maximum(info, 1e-300)), n)


def rate_of_variance(q: np.ndarray, q_sigma: np.ndarray, n: np.ndarray) -> RateEstimate:
    """The rate sqrt(q) of a per-month variance ``q`` (P,) with 1-sigma ``q_sigma``: its own
    1-sigma by the delta method, q_sigma / (2 sqrt q), with sqrt q floored at sqrt(q_sigma) so a
    rate at 0 keeps a finite sigma; NaN where ``n`` (changes behind it) is 0."""
    rate = np.sqrt(q)
    rate_sigma = q_sigma / (2.0 * np.maximum(rate, np.sqrt(q_sigma)))
    empty = n == 0
    rate[empty] = np.nan
    rate_sigma[empty] = np.nan
    return RateEstimate(rate, rate_sigma, n.astype(int))
