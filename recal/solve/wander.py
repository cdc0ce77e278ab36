"""Bias wander between windows: a Gauss-Markov model of each triad's bias and what it does to the
window invariants' covariance, in state-space form (time and memory linear in the windows).

A window's mean carries its own white noise (its sem) and the bias the sensor had at that time.
A FOG's bias wanders between windows (bias instability, rate random walk, temperature history),
an accelerometer's too; the constant part is the calibrated bias, the rest is noise that two
windows share the more, the closer they are in time. Modelled here, per triad and axis, as a
first-order Gauss-Markov process of steady-state 1-sigma ``sigma`` (output units) and
correlation time ``tau_s``::

    cov(b_i, b_j) = sigma^2 exp(-|t_i - t_j| / tau)       (t: the windows' mid-times, s)

A window's invariants see the bias through their sensitivity to the outputs, so the residuals
of the gyro norm, accel norm and dot product of all windows get a full covariance

    Sigma = D^2 + sum_axes (g_a g_a^T) * sigma_a^2 * rho_a(|t_i - t_j|)

(D: the windows' own noise; g_a: each residual's sensitivity to axis a of its triad's output).
That covariance is dense (R^2 memory, R^3 time) but its process is a Markov chain: sampled at
the windows in time order, the bias state x_m (the 3 or 6 axes with wander) follows

    x_m = Phi_m x_{m-1} + w_m,   Phi_m = exp(-gap_m / tau) per axis,   var w_m = sigma^2 (1 - Phi_m^2)

(restarted at each ``session``: its clock restarts, its windows are independent of the last
session's), and window m's residuals observe it, r_m = H_m x_m + e_m, with H_m their
sensitivity rows over the window noise (a :class:`WanderSensitivity`: one window index and one
3-vector per residual and triad). Everything is computed on that chain:

* the whitening (:class:`Whitening`, used by :class:`recal.solve.problem.Problem`) is the Kalman
  filter's standardised innovations: the gains depend on the model only, so the innovations of
  any number of residual vectors are one block-bidiagonal banded solve;
* the restricted likelihood :func:`estimate_wander` profiles over (sigma, tau) uses the banded
  precision of the state, K^-1 + H^T H (block-tridiagonal), and the determinant lemma and
  Woodbury identity: log det C = log det(K^-1 + H^T H) + log det K and
  C^-1 = I - H (K^-1 + H^T H)^-1 H^T; a batch of candidates is one banded Cholesky (LAPACK
  pbtrf of the candidates' matrices stacked along the band) and one banded triangular solve
  for the residuals and the Jacobian's columns.

:class:`recal.solve.problem.Problem` whitens the window residuals so the least-squares fit is a
generalised one and the reported sigma includes the wander. A random walk over the span of the
windows behaves, after the constant bias is taken out, like a Gauss-Markov process with a
correlation time of that span: it is covered by a long ``tau_s``.

:func:`estimate_wander` finds sigma and tau of each triad from the standardised residuals of a
fit (restricted maximum likelihood over a grid of correlation times, a likelihood-ratio test
against no wander); where no time columns exist the windows are taken as independent (tau 0: a
per-window inflation, said so). :func:`wander_gain` is that test's statistic for a given model.
The dense forms (:func:`correlation`, :func:`wander_covariance`, :func:`whitener`) remain as
references for small problems and tests.

The parts live in modules of their own (issue 38), each one idea:

* :mod:`recal.solve.wander_model`: :class:`~recal.solve.wander_model.TriadWander`,
  :class:`~recal.solve.wander_model.WanderModel` and their JSON, the windows' times and
  sessions, :func:`~recal.solve.wander_model.possible_wander`;
* :mod:`recal.solve.wander_chain`: the windows as a Markov chain (the residuals' sensitivity,
  the chain's order and gaps, the transition, the observation matrix);
* :mod:`recal.solve.wander_covariance`: the whitening, the covariance a problem carries, the
  drift test's :func:`innovations` and the dense references;
* :mod:`recal.solve.wander_likelihood`: the restricted likelihood and :func:`wander_gain`;
* :mod:`recal.solve.wander_estimate`: the correlation times searched (:func:`tau_floor_s`,
  :func:`correlation_times`) and :func:`estimate_wander`.

This module keeps the overview, and the names docs/noise.md gives under this path.
"""

from __future__ import annotations

from recal.solve.wander_covariance import innovations
from recal.solve.wander_estimate import correlation_times, tau_floor_s

__all__ = ["correlation_times", "innovations", "tau_floor_s"]

#: The other names this module held before issue 38's split, and where each lives now: served
#: with a DeprecationWarning until 0.3.0 (CHANGELOG), as recal._moved serves the older paths.
_MOVED = {
    **dict.fromkeys(
        ("TriadWander", "WanderModel", "window_times", "window_sessions", "possible_wander"),
        "recal.solve.wander_model",
    ),  # fmt: skip
    **dict.fromkeys(("WanderSensitivity", "as_sensitivity"), "recal.solve.wander_chain"),
    **dict.fromkeys(
        ("Whitening", "WanderCovariance", "correlation", "wander_covariance", "whitener"),
        "recal.solve.wander_covariance",
    ),  # fmt: skip
    **dict.fromkeys(
        ("RestrictedLikelihood", "restricted_nll", "wander_gain"), "recal.solve.wander_likelihood"
    ),  # fmt: skip
    **dict.fromkeys(("TAU_GRID_S", "WanderFit", "estimate_wander"), "recal.solve.wander_estimate"),
}


def __getattr__(name: str) -> object:
    target = _MOVED.get(name)
    if target is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    import warnings

    warnings.warn(
        f"{__name__}.{name} moved to {target}.{name}; the old path goes in 0.3.0",
        DeprecationWarning,
        stacklevel=2,
    )
    return getattr(importlib.import_module(target), name)
