"""Is an effect needed when the misfit may be noise? The family-wise test of candidate effects
against a noise null (a wander, or an independent excess, recal.diagnose.hypotheses), by a
parametric bootstrap of the restricted likelihood ratio.

The statistic of a candidate is the profile likelihood ratio of the current model plus the
effect over the current model, the coefficients re-fitted (generalised least squares) and the
noise of the effect's triad re-fitted on both sides (its sigma and tau profiled over a grid; the
other triad's noise held at the null's estimate):

    LR = min over (sigma, tau) of -2 ln L(current) - min over (sigma, tau) of -2 ln L(+effect)

Not the restricted (REML) likelihood, which estimates the noise well but compares models with
different coefficients badly: its ln det(Q' C^-1 Q) rewards every direction a model adds where
the noise is large (on the Xsens recording, whose gyro misfit is an excess of 7 deg/h, the
9-parameter g-sensitivity gained a restricted ratio of 43 on the null's own draws, median).

Tens of windows pin a wander's sigma and tau poorly, and a Gauss-Markov bias with a correlation
time near the session's span often looks like a trend: an effect that follows time, or a
temperature that ramps with it, then takes a share of one wander realisation, and the wander
fitted after it shrinks. Against chi-square(k) such an LR comes out at 15-20 on wander alone
(benchmarks/bench_wander.py's units; 5 of 6 proposed an effect). So the null distribution is
drawn instead: residuals from the null's own noise (its maximum-likelihood wander or excess),
every candidate's LR computed exactly as for the data, and a candidate's family-wise p the share
of draws in which the smallest nominal p of all candidates is below its own (Westfall-Young
min-p, as the F-test's bootstrap in recal.diagnose.candidates). An effect that follows a
measured driver the wander cannot mimic (a temperature cycle, the orientation) keeps an LR far in
the tail; one that a wander realisation mimics does not.

Linearised and dense (R^2 memory, R^3 per correlation time): each model's coefficients enter as
the span of their Jacobian (REML needs no more), each correlation time is one
eigendecomposition, each draw a few matrix products.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.linalg import solve_triangular

from recal.solve.wander_chain import WanderSensitivity, as_sensitivity
from recal.solve.wander_covariance import wander_covariance
from recal.solve.wander_model import TriadWander, WanderModel

#: Parametric-bootstrap draws of the null (family-wise p resolution 1 / (draws + 1)).
NOISE_NULL_DRAWS = 400
#: The bootstrap is dense (an (R, R) eigendecomposition per correlation time): up to this many
#: window residuals (500 windows with both triads); past it recal.diagnose.candidates takes
#: the likelihood ratio against chi-square with Bonferroni, and says so in the candidate's
#: ``hypotheses["test"]``.
NOISE_NULL_MAX_RESIDUALS = 1500
#: The sigma grid: log10 steps of about 0.17 around the windows' own noise (a step that size
#: costs under 0.2 in 2 ln L at the maximum), from 1e-3 of it to 300 times it or 30 times the
#: null's sigma, whichever is larger.
_LOG_STEP = 0.17


def _log_sigma(top: float) -> np.ndarray:
    """log10 (sigma / the windows' noise) of the grid; ``top`` log10 of the null's own."""
    hi = max(2.5, top + 1.5)
    return np.linspace(-3.0, hi, int(np.ceil((hi + 3.0) / _LOG_STEP)) + 1)


@dataclass(frozen=True)
class NoiseNullTest:
    """Per candidate: the observed LR, its nominal chi-square p and its family-wise p."""

    lr: np.ndarray
    p_nominal: np.ndarray
    p_family: np.ndarray


def orthonormal_span(J: np.ndarray) -> np.ndarray:
    """Orthonormal basis of J's column space (null directions dropped)."""
    U, sv, _ = np.linalg.svd(J, full_matrices=False)
    return U[:, sv > 1e-10 * sv.max()] if sv.size and sv.max() > 0 else U[:, :0]


def _profile_min(
    Y: np.ndarray,
    Q: np.ndarray,
    lam: np.ndarray,
    V: np.ndarray,
    s2_grid: np.ndarray,
) -> np.ndarray:
    """min over s2 of -2 ln L_R (up to a constant shared by every model and draw) of each
    column of Y (already whitened by the other triads' noise), for the model spanning Q:
    covariance I + s2 V diag(lam) V'."""
    Z = V.T @ Y  # (R, B)
    Jv = V.T @ Q  # (R, k)
    best = np.full(Y.shape[1], np.inf)
    for s2 in s2_grid:
        d = 1.0 / (1.0 + s2 * lam)
        A = Jv.T @ (d[:, None] * Jv)
        L = np.linalg.cholesky(A + 1e-12 * np.eye(len(A)))
        b = solve_triangular(L, Jv.T @ (d[:, None] * Z), lower=True)
        val = (  # the profile likelihood: no ln det(Q' C^-1 Q) (module doc)
            np.einsum("rb,rb->b", Z, d[:, None] * Z)
            - np.einsum("kb,kb->b", b, b)
            + float(np.sum(np.log1p(s2 * lam)))
        )
        best = np.minimum(best, val)
    return best


def noise_null_test(
    r_std: np.ndarray,
    sigma_w: np.ndarray,
    sensitivity: WanderSensitivity | Mapping[str, np.ndarray],
    t: np.ndarray | None,
    sessions: np.ndarray | None,
    taus: Sequence[float],
    J0: np.ndarray,
    candidates: Sequence[tuple[str, np.ndarray, int, np.ndarray]],
    null: WanderModel,
    rng: np.random.Generator,
    draws: int = NOISE_NULL_DRAWS,
) -> NoiseNullTest:
    """The module's test. ``r_std`` (R,) the current fit's standardised window residuals,
    ``J0`` (R, k) their Jacobian along its directions; ``candidates``: (sensor, Je (R, k_e), dk,
    r_e (R,)) per candidate effect: its extended fit's Jacobian and standardised residuals;
    ``null``: the null's noise (the admitted triads at their maximum-likelihood sigma and
    tau)."""
    R = len(r_std)
    C = len(candidates)
    sens = as_sensitivity(sensitivity)
    if C == 0:
        return NoiseNullTest(np.zeros(0), np.zeros(0), np.zeros(0))
    # draws from the null's noise; each model's observed column is its own fit's residual (the
    # fits are non-linear: an effect that moves the coefficients far is linearised where its
    # own fit put them, not where the current model's did)
    cov = np.eye(R) + wander_covariance(sensitivity, t, null, sessions) / np.outer(sigma_w, sigma_w)
    D = np.linalg.cholesky(cov) @ rng.standard_normal((R, draws))
    data = {-1: (r_std, J0)}  # -1: the current model
    data.update({i: (c[3], c[1]) for i, c in enumerate(candidates)})
    stat = np.zeros((C, draws + 1))
    for s in {c[0] for c in candidates}:
        if s not in sens.sensors:
            continue
        one = WanderSensitivity(sens.window, {s: sens.rows[s]}, sens.n_windows)
        others = WanderModel({k: v for k, v in null.triads.items() if k != s})
        base = np.eye(R) + wander_covariance(sensitivity, t, others, sessions) / np.outer(
            sigma_w, sigma_w
        )
        L = np.linalg.cholesky(base)
        Dw = solve_triangular(L, D, lower=True)
        members = [i for i, c in enumerate(candidates) if c[0] == s]
        Ys, Qs = {}, {}
        for key in (-1, *members):
            r, J = data[key]
            Ys[key] = np.column_stack([solve_triangular(L, r, lower=True), Dw])
            Qs[key] = orthonormal_span(solve_triangular(L, J, lower=True))
        best = {key: np.full(draws + 1, np.inf) for key in Qs}
        for tau in taus:
            unit_model = WanderModel({s: TriadWander(np.ones(3), np.full(3, tau))})
            U = wander_covariance(one, t, unit_model, sessions)
            U = U / np.outer(sigma_w, sigma_w)
            diag = np.diag(U)
            if not (diag > 0).any():
                continue
            X = solve_triangular(L, U, lower=True)
            lam, V = np.linalg.eigh(solve_triangular(L, X.T, lower=True))
            lam = np.clip(lam, 0.0, None)
            scale2 = 1.0 / float(np.mean(diag[diag > 0]))  # sigma^2 at the windows' own noise
            # up to well past the null's own sigma: a misfit of thousands of times the window
            # noise (a large missing effect) must be within the null's profile, or every draw
            # looks like an effect
            own = null.triads.get(s)
            top = (
                0.0
                if own is None
                else math.log10(max(float(own.sigma.max()) ** 2 / scale2, 1.0)) / 2
            )
            grid = np.concatenate([[0.0], scale2 * 10.0 ** (2 * _log_sigma(top))])
            for key, Q in Qs.items():
                best[key] = np.minimum(best[key], _profile_min(Ys[key], Q, lam, V, grid))
        for i in members:
            stat[i] = best[-1] - best[i]
    dks = np.array([c[2] for c in candidates], float)
    nominal = stats.chi2.sf(np.maximum(stat, 0.0), dks[:, None])  # (C, draws + 1)
    min_p = nominal[:, 1:].min(axis=0)
    p_family = (1 + np.sum(min_p[None, :] <= nominal[:, :1], axis=1)) / (1 + draws)
    return NoiseNullTest(stat[:, 0], nominal[:, 0], p_family)
