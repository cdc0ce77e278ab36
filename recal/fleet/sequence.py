"""The ageing rate from each unit's whole sequence of versions (issue 37).

**The model.** A coefficient's true value random-walks in months of service (variance
``q dt`` over ``dt`` months, ``q = s**2``, ``s`` the rate); each version ``x_k`` is the true
value plus its own measurement error of variance ``sigma_k**2``, independent from version to
version. The likelihood is that of the sequence ``x_0 .. x_n`` itself. With the starting value
unknown (diffuse) it is exactly the likelihood of the consecutive differences
``d_k = x_k - x_{k-1}``, which are *not* independent: ``d_k`` and ``d_{k+1}`` share ``x_k``'s
error, so

    Var(d_k)            = q dt_k + sigma_{k-1}**2 + sigma_k**2
    Cov(d_k, d_{k+1})   = -sigma_k**2

a tridiagonal covariance per unit and coefficient. Treating the differences as independent
(recal.fleet.estimate) keeps the rate's estimate consistent but not its 1-sigma (the squared
differences of one unit are positively correlated, so they hold less information than their
number says) nor the outlier test's chi-square (its variance is larger than its degrees of
freedom say). Here the covariance is factorised exactly.

**Vectorised.** Every difference of every unit and coefficient is stacked into one chain, with
a zero coupling where a unit (or a coefficient) ends: one block-diagonal tridiagonal matrix,
factorised by LAPACK's banded Cholesky in one call (scipy.linalg.cholesky_banded), whose
diagonal gives every block's log-determinant and whose solve gives every block's quadratic
form, summed per coefficient and per unit with np.bincount. No Python loop over units,
versions or coefficients: one factorisation per trial value of the rates of all coefficients.
A coefficient a version held or lacked (NaN) is left out of that coefficient's chain: the walk
across the gap is still a walk, over the longer time.

**Which versions.** Every version whose estimate is sound: the accepted ones and those the
vessel's gate rejected for a jump (service/gate.py: some estimated coefficient moved more than
``max_change_sigma`` combined sigmas from the current accepted version). The gate's decision
is a function of what the shore stores (the new version, the accepted one it was compared
with, the allowance in force), so with every version in the likelihood the gate selects
nothing away: the likelihood of the whole sequence is the same with or without the gate, and
the estimate is unbiased whatever the gate did. Learning from the accepted ones alone censors
the largest changes (a rate biased low, which then tightens the gate that censors them). A
truncated likelihood of the accepted ones could undo that only by knowing, for every decision,
the limit, ``allow_jump``, the drift's ``change_expected``, which coefficients were estimated
and which fleet prior and months the vessel used, and it would throw away exactly the versions
that say most about fast ageing. Versions rejected for another reason (residuals, observability,
a poorly determined scale, navigation, unconfirmed effects) are left out by the caller: their
estimates are not trusted, and leaving them out depends on no coefficient's value.

**The estimate.** Per coefficient, ``q`` maximising the log-likelihood: 0 where the likelihood
falls from ``q = 0`` on, else Newton's method on ``log q`` from the moment estimate, its slope
and curvature from central differences of the exact log-likelihood, a step that would lower it
halved (vectorised over the coefficients: three factorisations per step, four to six steps).
Its 1-sigma is the inverse of the observed information (the curvature in ``q`` at the maximum),
carried to ``s`` by the delta method; at ``q = 0`` it is floored as in recal.fleet.estimate.

**Per unit.** Under the model, a unit's quadratic form ``d' Sigma^-1 d`` summed over its
coefficients is chi-square with as many degrees of freedom as differences: the outlier test
(recal.fleet.outliers) without the independence it assumed before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded

from recal.fleet.estimate import RateEstimate, rate_of_variance
from recal.fleet.history import VersionTable, is_relative

#: Newton steps on log q at most (from the moment estimate it converges in four to six).
NEWTON_STEPS = 40
#: A Newton step on log q is at most this (a factor e**2 on q); the search ends below TOLERANCE.
MAX_STEP = 2.0
TOLERANCE = 1e-6
#: Step in log q of the central differences that give the slope and curvature.
CURVATURE_STEP = 1e-3
#: q below this fraction of the changes' scale per month is q = 0.
FLOOR = 1e-8
_LOG_2PI = np.log(2.0 * np.pi)


@dataclass(frozen=True)
class Chain:
    """Every difference of consecutive sound versions, per unit and coefficient, stacked
    coefficient-major then unit then time (one row per difference)."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    coef: np.ndarray  # (N,) coefficient index
    unit: np.ndarray  # (N,) unit index
    delta: np.ndarray  # (N,) x_k - x_{k-1} (relative to the unit's first value for scales)
    months: np.ndarray  # (N,) dt_k
    var_before: np.ndarray  # (N,) sigma_{k-1}**2
    var_after: np.ndarray  # (N,) sigma_k**2
    linked: np.ndarray  # (N,) bool: row n and n+1 share x_k (same unit and coefficient)
    rejected: np.ndarray  # (N,) bool: x_k was rejected by the vessel's gate

    def __len__(self) -> int:
        return len(self.delta)

    def without(self, units: Sequence[str]) -> Chain:
        """The chain of every unit but ``units`` (their blocks dropped whole)."""
        drop = np.isin(np.asarray(self.units, dtype=object), list(units))
        keep = ~drop[self.unit]
        linked = self.linked & keep & np.r_[keep[1:], False]
        return Chain(self.names, self.units, self.coef[keep], self.unit[keep],
                     self.delta[keep], self.months[keep], self.var_before[keep],
                     self.var_after[keep], linked[keep], self.rejected[keep])  # fmt: skip

    def counts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per coefficient: (differences, units with one, differences ending in a rejected
        version)."""
        p, n = len(self.names), len(self.units)
        changes = np.bincount(self.coef, minlength=p)
        pairs = np.zeros((p, n), bool)
        pairs[self.coef, self.unit] = True
        rejected = np.bincount(self.coef, weights=self.rejected, minlength=p).astype(int)
        return changes, pairs.sum(1), rejected

    # ---- the likelihood ----------------------------------------------------------------------
    def _solve(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(log-determinant, quadratic form) per row for rates ``q`` (P,): the rows of one block
        sum to the block's ``log det Sigma`` and ``d' Sigma^-1 d``."""
        band = np.zeros((2, len(self)))
        band[0] = q[self.coef] * self.months + self.var_before + self.var_after
        band[1, :-1] = np.where(self.linked[:-1], -self.var_after[:-1], 0.0)
        factor = cholesky_banded(band, lower=True, check_finite=False)
        solved = cho_solve_banded((factor, True), self.delta, check_finite=False)
        return 2.0 * np.log(factor[0]), self.delta * solved

    def loglik(self, q: np.ndarray) -> np.ndarray:
        """(P,) the log-likelihood of each coefficient's differences for rates ``q`` (P,)."""
        if len(self) == 0:
            return np.zeros(len(self.names))
        logdet, quad = self._solve(np.maximum(np.asarray(q, float), 0.0))
        terms = logdet + quad + _LOG_2PI
        return -0.5 * np.bincount(self.coef, weights=terms, minlength=len(self.names))

    def unit_statistics(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(statistic, dof) per unit: ``d' Sigma^-1 d`` over its coefficients with a finite rate
        ``q`` (P,) and its number of differences; chi-square under "ages like its model"."""
        q = np.asarray(q, float)
        use = np.isfinite(q)[self.coef]
        stat = np.zeros(len(self.units))
        dof = np.zeros(len(self.units), int)
        if not np.any(use):
            return stat, dof
        _, quad = self._solve(np.where(np.isfinite(q), np.maximum(q, 0.0), 0.0))
        stat = np.bincount(self.unit[use], weights=quad[use], minlength=len(self.units))
        dof = np.bincount(self.unit[use], minlength=len(self.units))
        return stat, dof

    # ---- the estimate ------------------------------------------------------------------------
    def rate(self) -> RateEstimate:
        """The maximum-likelihood rate ``s = sqrt(q)`` per coefficient and its 1-sigma."""
        p = len(self.names)
        n = np.bincount(self.coef, minlength=p)
        if len(self) == 0:
            nan = np.full(p, np.nan)
            return RateEstimate(nan, nan.copy(), n)
        # the scale of q: the changes' excess over the measurement errors per month
        months = np.maximum(np.bincount(self.coef, weights=self.months, minlength=p), 1e-300)
        noise = np.bincount(self.coef, weights=self.var_before + self.var_after, minlength=p)
        squares = np.bincount(self.coef, weights=self.delta**2, minlength=p)
        scale = np.maximum(noise, squares) / months
        scale = np.where(scale > 0, scale, 1.0)
        lowest = np.log(scale * FLOOR)
        # q = 0 where the likelihood falls from 0 on (it is unimodal in q)
        tiny = scale * FLOOR
        zero = self.loglik(tiny) <= self.loglik(np.zeros(p))
        # elsewhere Newton on log q from the moment estimate, safeguarded
        theta = np.log(np.maximum((squares - noise) / months, scale * 1e-3))
        theta = np.where(zero, lowest, theta)
        active = ~zero
        f0 = self.loglik(np.exp(theta))
        grad = curv = np.zeros(p)
        for _ in range(NEWTON_STEPS):
            h = CURVATURE_STEP
            fm, fp = self.loglik(np.exp(theta - h)), self.loglik(np.exp(theta + h))
            grad, curv = (fp - fm) / (2 * h), (fp - 2 * f0 + fm) / h**2
            step = np.where(curv < 0, -grad / np.where(curv < 0, curv, -1.0), np.sign(grad))
            step = np.where(active, np.clip(step, -MAX_STEP, MAX_STEP), 0.0)
            if np.all(np.abs(step) < TOLERANCE):
                break
            for _ in range(30):  # halve a step that lowers the likelihood
                trial = self.loglik(np.exp(theta + step))
                worse = trial < f0 - 1e-9 * np.abs(f0)
                if not np.any(worse):
                    break
                step = np.where(worse, 0.5 * step, step)
            theta = theta + step
            f0 = np.where(step != 0, trial, f0)
            sank = active & (theta < lowest)  # walking down to q = 0
            zero |= sank
            active &= ~sank
        q = np.where(zero, 0.0, np.exp(theta))
        # observed information in q: -d2l/dq2 = -(curv - grad) / q**2 in log q (grad ~ 0 at
        # the maximum); at q = 0 a forward difference in q itself
        info = -(curv - grad) / np.maximum(q, 1e-300) ** 2
        if np.any(zero):
            h = scale * 1e-3
            f = [self.loglik(k * h) for k in (0.0, 1.0, 2.0)]
            info = np.where(zero, -(f[2] - 2 * f[1] + f[0]) / h**2, info)
        return rate_of_variance(q, 1.0 / np.sqrt(np.maximum(info, 1e-300)), n)


def version_chain(table: VersionTable) -> Chain:
    """The :class:`Chain` of ``table``'s versions (every row: the caller leaves out the
    versions whose estimates are not trusted). Vectorised over units, versions and
    coefficients."""
    names, p = table.names, len(table.names)
    values, sigma = table.values, table.sigma
    ok = np.isfinite(values) & np.isfinite(sigma) & (sigma >= 0)
    rel = np.array([is_relative(n) for n in names], bool)
    ok &= ~rel[None, :] | (np.abs(np.where(ok, values, 0.0)) > 0)
    coef, row = np.nonzero(ok.T)  # coefficient-major, then row (unit, then time)
    unit = table.unit[row]
    start = np.ones(len(row), bool)
    start[1:] = (coef[1:] != coef[:-1]) | (unit[1:] != unit[:-1])
    first = np.maximum.accumulate(np.where(start, np.arange(len(row)), 0))
    ref = np.where(rel[coef], np.abs(values[row[first], coef[first]]), 1.0) if len(row) else 1.0
    y = values[row, coef] / ref
    var = (sigma[row, coef] / ref) ** 2
    # a version reporting a zero 1-sigma would make the covariance singular at q = 0
    scale = np.zeros(p)
    if len(var):
        pos = var > 0
        for_scale = np.bincount(coef[pos], weights=var[pos], minlength=p)
        scale = for_scale / np.maximum(np.bincount(coef[pos], minlength=p), 1)
    var = np.maximum(var, 1e-12 * scale[coef])
    a = np.flatnonzero(~start[1:]) if len(row) else np.zeros(0, int)
    b = a + 1
    linked = np.zeros(len(a), bool)
    linked[:-1] = b[:-1] == a[1:]
    return Chain(tuple(names), table.units, coef[a], unit[a], y[b] - y[a],
                 table.months[row[b]] - table.months[row[a]], var[a], var[b], linked,
                 ~table.accepted[row[b]])  # fmt: skip


def sequence_rate(table: VersionTable) -> RateEstimate:
    """The maximum-likelihood rate per coefficient of ``table``'s version sequences."""
    return version_chain(table).rate()
