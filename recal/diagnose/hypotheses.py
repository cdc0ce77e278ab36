"""Effect or noise: what explains a fitted model's misfit beyond the windows' own noise.

Every model diagnose fits (the baseline, and the baseline with each candidate effect) is fitted
with the windows taken as independent. Its window residuals are then asked whether they share a
bias wander (:mod:`recal.solve.wander`), by the same restricted likelihood (REML) the wander fit
uses: the coefficients are re-fitted, linearised, under each candidate covariance, so a wander
that looks like a coefficient is not counted twice. Per triad the correlation time is chosen
among 0 and the times the windows' spacing can show (:func:`recal.solve.wander_estimate.tau_floor_s`):

* tau at or above the floor: a **wander**, a bias the windows share the more, the closer they are;
* tau 0: **excess** scatter, independent on each window. Neighbouring windows do not share it,
  so it is not a wander they can show: it is model error (an effect that changes with the
  orientation, a missing term), or a wander faster than the spacing, and diagnose says so.

Comparing models with different coefficients needs a likelihood that does not depend on how
their coefficients are scaled: the profile likelihood (coefficients re-fitted by generalised
least squares), which for independent windows is the chi^2 of the fit. So each hypothesis gets one figure on one scale (:attr:`NoiseFit.ic`)::

    IC = chi^2 - gain + 11.34 x (triads with wander or excess) + (effect directions) x ln(n)

gain being 2 ln of the profile likelihood ratio of the noise over none (0 without; whether a
fit has noise at all is decided in that fit by the restricted one, as calibrate decides it). The
noise pays what calibrate's wander test makes it earn (:data:`WANDER_SIGNIFICANCE`), an effect
its BIC price. The four hypotheses of a candidate (nothing, noise, effect, effect plus noise)
are the baseline's two figures and the candidate's two: the candidate explains the misfit when
its best beats the baseline's best. An effect whose driver is measured and which explains the
residual fits it with a white remainder; a wander explains it only by being flexible and pays
the determinant of its covariance for that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.diagnose.fit import Fit
from recal.diagnose.noise_test import orthonormal_span
from recal.solve.wander_chain import WanderSensitivity
from recal.solve.wander_covariance import Whitening
from recal.solve.wander_estimate import (
    WANDER_SIGNIFICANCE,
    correlation_times,
    estimate_wander,
    tau_floor_s,
)
from recal.solve.wander_fit import WANDER_MIN_SPAN_S
from recal.solve.wander_likelihood import wander_gain
from recal.solve.wander_model import TriadWander, WanderModel, window_sessions, window_times

#: Names of the noise hypotheses, as the JSON gives them.
WHITE, NOISE = "independent", "noise"


@dataclass(frozen=True)
class TriadNoise:
    """One triad's noise beyond the windows' own, at its maximum-likelihood pair."""

    sensor: str
    sigma: float  # steady-state 1-sigma, output units
    tau_s: float  # 0: independent excess
    gain: float  # 2 ln L_R gain of this triad (the others' noise held)
    admitted: bool  # earns WANDER_SIGNIFICANCE

    @property
    def kind(self) -> str:
        return "excess" if self.tau_s == 0.0 else "wander"

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "sensor": self.sensor,
            "kind": self.kind,
            "sigma": self.sigma,
            "tau_s": self.tau_s,
            "gain_2lnL": round(self.gain, 3),
            "admitted": self.admitted,
        }


@dataclass(frozen=True)
class NoiseFit:
    """A fitted model's misfit as noise: its chi^2 with independent windows and, per triad,
    the wander or excess its residuals hold (module doc)."""

    chi2: float
    triads: tuple[TriadNoise, ...] = ()
    #: 2 ln L_R of the admitted triads' noise together over none
    gain: float = 0.0
    #: the same with every triad's maximum-likelihood noise, admitted or not (for the
    #: likelihood-ratio test of an effect against a noise null, where the noise is re-fitted)
    gain_all: float = 0.0
    tau_floor_s: float = 0.0
    #: what the noise was estimated from (the test against a noise null reuses it)
    inputs: WindowInputs | None = field(default=None, repr=False, compare=False)

    @property
    def admitted(self) -> tuple[TriadNoise, ...]:
        return tuple(t for t in self.triads if t.admitted)

    def ic(self, with_noise: bool) -> float:
        """chi^2 - gain + the noise's price (module doc), without the effect's price."""
        if not with_noise or not self.admitted:
            return self.chi2
        return self.chi2 - self.gain + WANDER_SIGNIFICANCE * len(self.admitted)

    @property
    def best_with_noise(self) -> bool:
        """True when a triad's noise earned its price in its own fit: the restricted likelihood
        ratio, as calibrate decides (within one fit the restricted likelihood is the right
        one; the profile figures of :meth:`ic` compare fits)."""
        return bool(self.admitted)

    @property
    def best_ic(self) -> float:
        """The figure of this fit with its own noise decision."""
        return self.ic(self.best_with_noise)

    @property
    def kinds(self) -> set[str]:
        return {t.kind for t in self.admitted}

    def model(self) -> WanderModel:
        """The admitted noise as a wander model (tau 0 where it is excess)."""
        return _as_model(self.admitted)

    def to_json_dict(self) -> dict[str, Any]:
        return {
            WHITE: _num(self.ic(False)),
            NOISE: _num(self.ic(True)) if self.admitted else None,
            "triads": [t.to_json_dict() for t in self.triads],
            "tau_floor_s": self.tau_floor_s,
        }


def _as_model(triads: tuple[TriadNoise, ...]) -> WanderModel:
    """Triads' noise (isotropic sigma, one tau) as a wander model."""
    return WanderModel(
        {t.sensor: TriadWander(np.full(3, t.sigma), np.full(3, t.tau_s)) for t in triads},
        "diagnose: maximum likelihood",
    )


def _num(v: float) -> float | None:
    return round(float(v), 3) if math.isfinite(v) else None


@dataclass(frozen=True)
class WindowInputs:
    """What the noise of a fit's window residuals is estimated from: the standardised residuals
    (R,), their own 1-sigma, the Jacobian rows along the fit's directions (R, k), each triad's
    sensitivity to its output (recal.solve.problem.Problem.wander_sensitivity), the windows'
    mid-times and sessions, and the correlation times tried."""

    r_std: np.ndarray
    sigma: np.ndarray
    jacobian: np.ndarray
    sensitivity: Any
    t: np.ndarray | None
    sessions: np.ndarray | None
    taus: list[float]
    tau_floor_s: float = 0.0


def window_inputs(fit: Fit) -> WindowInputs | None:
    """The window part of ``fit`` (None without window invariants, known noise or a Jacobian)."""
    p = fit.problem
    windows = p.window_invariants
    if not windows or not p.noise_known or fit.jac is None or not np.isfinite(fit.rss):
        return None
    t = window_times(p.positions.columns, p.M)
    sessions = window_sessions(p.positions.columns, p.M)
    raw = p.raw_residuals(fit.theta[None])
    sigma_w = p.window_sigma()
    r_std = np.concatenate([raw[n][0] for n in windows]) / sigma_w
    span = 0.0 if t is None else float(np.ptp(t))
    # over a session shorter than calibrate looks for wander in, a wander with tau near the
    # span is a trend, which no test tells from a drift: there only independent excess is tried
    # (a 52-minute session's 0.03 deg/h/h drift was called a wander of tau 1 h)
    taus = correlation_times(t, sessions, span) if span >= WANDER_MIN_SPAN_S else [0.0]
    sens = p.wander_sensitivity(fit.theta)
    floor = 0.0 if t is None else tau_floor_s(t, sessions)
    extra = fit.residual()[len(r_std) :]
    if not extra.size:
        return WindowInputs(r_std, sigma_w, fit.jac, sens, t, sessions, taus, floor)
    # The other residuals (slews, known rotations, closed turns) pin coefficients too: without
    # them the restricted likelihood takes a gyro the slews pin for free and finds no misfit to
    # explain (the Xsens recording: a gyro norm 8.9 times its floor, an excess gain of 0). They
    # join as windows of their own, each its own session (independent, no wander: zero
    # sensitivity), so the same linear-time likelihood serves.
    X, M = extra.size, sens.n_windows
    sens = WanderSensitivity(
        np.concatenate([sens.window, M + np.arange(X)]),
        {s: np.vstack([g, np.zeros((X, 3))]) for s, g in sens.rows.items()},
        M + X,
    )
    own = np.zeros(M) if sessions is None else np.asarray(sessions, float)
    return WindowInputs(
        np.concatenate([r_std, extra]),
        np.concatenate([sigma_w, np.ones(X)]),
        fit.jac,
        sens,
        None if t is None else np.concatenate([t, np.zeros(X)]),
        None if t is None else np.concatenate([own, own.max(initial=0.0) + 1.0 + np.arange(X)]),
        taus,
        floor,
    )


def noise_fit(fit: Fit) -> NoiseFit:
    """Wander or excess in ``fit``'s window residuals (module doc); ``fit`` must have been made
    with independent windows."""
    w = window_inputs(fit)
    if w is None:
        return NoiseFit(fit.rss)
    r_std, sigma_w, J, sens, t, sessions = (
        w.r_std,
        w.sigma,
        w.jacobian,
        w.sensitivity,
        w.t,
        w.sessions,
    )
    _, fits = estimate_wander(r_std, sigma_w, sens, t, taus=w.taus, jacobian=J, sessions=sessions)
    triads = tuple(
        TriadNoise(
            f.sensor,
            float(f.sigma_ml),
            float(f.tau_ml_s),
            float(f.gain),
            bool(f.significant) and f.sigma_ml > 0,
        )  # fmt: skip
        for f in fits
    )

    Q = orthonormal_span(J)

    def gain_of(ts: tuple[TriadNoise, ...]) -> float:
        """2 ln of the *profile* likelihood ratio of the noise ``ts`` over none: the restricted
        gain plus ln det(Q' C^-1 Q) (Q the fit's directions, orthonormal). The restricted
        likelihood compares noise models of one fit; across fits with different coefficients
        its ln det(Q' C^-1 Q) term rewards a model for every direction it adds where the noise
        is large (the Xsens recording's gyro excess: 9 such directions, a ratio of 43 on the
        null's own draws), so the figures compared across models are profile ones."""
        ts = tuple(x for x in ts if x.sigma > 0)
        if not ts:
            return 0.0
        model = _as_model(ts)
        restricted = wander_gain(r_std, sigma_w, sens, t, model, jacobian=J, sessions=sessions)
        WQ = Whitening(sigma_w, sens, t, model, sessions).apply(Q.T)  # (k, R): C^-1/2 Q
        return float(restricted + np.linalg.slogdet(WQ @ WQ.T)[1])

    admitted = tuple(x for x in triads if x.admitted)
    return NoiseFit(
        float(fit.rss),
        triads,
        gain=gain_of(admitted),
        gain_all=gain_of(triads),
        tau_floor_s=w.tau_floor_s,
        inputs=w,
    )


def describe(noise: NoiseFit) -> str:
    """'gyro wander 5.6 (output units), tau 8 h; accel excess 2e-05' of the admitted noise."""
    parts = []
    for x in noise.admitted:
        if x.kind == "wander":
            parts.append(f"{x.sensor} wander {x.sigma:.3g}, tau {x.tau_s / 3600:.3g} h")
        else:
            parts.append(f"{x.sensor} excess {x.sigma:.3g}")
    return "; ".join(parts) + " (output units)" if parts else ""
