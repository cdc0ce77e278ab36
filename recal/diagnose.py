"""Model discrepancy: where the fitted model fails, and which physical effect is missing.

:func:`diagnose` fits the model (seed terms plus any effects already chosen), compares each
invariant's residual with its noise floor, then tries every candidate effect of the catalogue
(conventions section 7) and of the user's plugins one at a time on top of it:

* ``delta_bic``: change of the Bayesian information criterion, chi^2 + k ln(n), where k counts
  the *observable* directions; negative means the effect earns its parameters.
* ``p_value``: F-test of the nested models (robust when the noise level is itself uncertain).
* ``significant``: p below 0.01 after a Bonferroni correction over the candidates, and
  ``delta_bic < 0``.
* ``explained_fraction``: share of the residual power above the noise floor that the effect
  removes (of all residual power when the noise is unknown).

All candidate fits share the baseline's residual weights, so their chi^2 values compare. The
greedy ``suggested_effects`` adds the best significant candidate and repeats until none is left.
A candidate the positions cannot show (e.g. a temperature term at constant temperature) is
listed with ``identifiable: false`` and the reason.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from recal.calibrate import UNITS, CalibrationOptions, CalibrationResult, build_models, calibrate
from recal.errors import RecalInputError
from recal.lm import covariance, solve_lm
from recal.model import ParameterLayout
from recal.observability import analyze
from recal.plugins import bind_context, values_by_term
from recal.positions import Positions
from recal.problem import Problem
from recal.terms import Term, catalogue_terms

ALPHA = 0.01


@dataclass
class Fit:
    """One model fitted with fixed residual weights."""

    effects: tuple[str, ...]
    problem: Problem
    theta: np.ndarray
    rank: int
    rss: float  # sum of squared whitened residuals (chi^2)
    verdict: str


@dataclass
class Candidate:
    effect: str
    explanation: str
    identifiable: bool
    reason: str = ""
    delta_bic: float = float("nan")
    p_value: float = float("nan")
    significant: bool = False
    explained_fraction: float = 0.0
    added_directions: int = 0
    rms_after: dict[str, float] = field(default_factory=dict)
    parameters: dict[str, float] = field(default_factory=dict)
    uncertainty: dict[str, float] = field(default_factory=dict)
    similar_to: list[str] = field(default_factory=list)
    #: Per-position raw residual of each invariant with the effect added (for the report's
    #: charts; not in the JSON).
    residuals_after: dict[str, np.ndarray] = field(default_factory=dict)
    #: What drives the effect, per position: its context columns (temperature_c,
    #: temperature_rate_c_per_h, time_h, specific_force_g (M, 3)); for an effect of the input
    #: itself (no context), the specific force when the accel is calibrated. Not in the JSON.
    drivers: dict[str, np.ndarray] = field(default_factory=dict)

    def to_json_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        return {
            "effect": self.effect,
            "delta_bic": num(self.delta_bic),
            "p_value": num(self.p_value),
            "significant": self.significant,
            "explained_fraction": self.explained_fraction,
            "identifiable": self.identifiable,
            "reason": self.reason,
            "added_directions": self.added_directions,
            "explanation": self.explanation,
            "rms_after": self.rms_after,
            "parameters": self.parameters,
            "uncertainty": {k: num(v) for k, v in self.uncertainty.items()},
            "similar_to": self.similar_to,
        }


@dataclass
class Diagnosis:
    baseline: CalibrationResult
    invariants: list[dict[str, Any]]
    candidates: list[Candidate]
    suggested_effects: list[str]
    baseline_effects: list[str]
    chi2_red: float  # baseline model
    final_chi2_red: float  # with the suggested effects added
    final_residuals: dict[str, np.ndarray]  # invariant -> per-position residual, suggested model

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "invariants": self.invariants,
            "candidates": [c.to_json_dict() for c in self.candidates],
            "suggested_effects": self.suggested_effects,
            "baseline_effects": self.baseline_effects,
            "chi2_red": _finite(self.chi2_red),
            "chi2_red_with_suggested": _finite(self.final_chi2_red),
            "noise_known": self.baseline.problem.noise_known,
            "method": "LM fits with the baseline's residual weights; F-test and BIC per candidate",
            "alpha": ALPHA,
        }


def _finite(v: float) -> float | None:
    """JSON has no NaN: an undefined figure is null."""
    return float(v) if np.isfinite(v) else None


def _fit(base: CalibrationResult, opt: CalibrationOptions, effects: Sequence[str]) -> Fit:
    """Fit the model with ``effects`` on the baseline's positions, prior and residual weights."""
    positions = base.problem.positions
    fresh = build_models(base.problem.sensors, effects, opt.plugin_terms, opt.t0_c)
    fresh = bind_context(fresh, positions, values_by_term(base.layout, base.theta_prior),
                         opt.latitude_deg, opt.height_m, with_slews=base.problem.slews is not None)  # fmt: skip
    # the baseline's own terms (calibrate may have tuned them, e.g. the typical bias change of
    # a gyro calibrated from slews), then the effects
    models = tuple(
        b.with_terms([t for t in m.terms if t.name not in {u.name for u in b.terms}])
        for b, m in zip(base.problem.models, fresh, strict=True)
    )
    layout = ParameterLayout(models)
    start = {n: base.theta[sl] for n, sl in base.layout.term_slices().items()}
    theta0 = np.concatenate(
        [np.asarray(start.get(t.name, t.neutral), float) for m in models for t in m.terms]
    )
    b = base.problem  # the baseline's slews and known rotations, so every fit sees the same data
    problem = Problem.build(positions, models, opt.latitude_deg, opt.height_m, theta0,
                            slews=b.slews, slew_earth_rate=b.slew_earth_rate,
                            known_rotations=b.known_rotations)  # fmt: skip
    problem = problem.with_sigma(b.sigma, b.sigma_source)
    typical = layout.typical(theta0)
    report = analyze(problem, theta0, typical)
    if report.verdict == "insufficient":
        return Fit(tuple(effects), problem, theta0, report.rank, float("nan"), report.verdict)
    lm = solve_lm(problem, theta0, typical[:, None] * report.basis)
    r = problem.residuals(lm.theta[None])[0]
    return Fit(tuple(effects), problem, lm.theta, report.rank, float(r @ r), report.verdict)


def _invariant_rows(fit: Fit) -> list[dict[str, Any]]:
    raw = fit.problem.raw_residuals(fit.theta[None])
    rows = []
    for n in fit.problem.invariant_names:
        r = raw[n][0]
        known = fit.problem.noise_known_for(n)
        floor = float(np.sqrt(np.mean(fit.problem.sigma[n] ** 2))) if known else None
        rms = float(np.sqrt(np.mean(r**2)))
        worst = np.argsort(-np.abs(r / fit.problem.sigma[n]))[:3]
        rows.append(
            {
                "name": n,
                "rms": rms,
                "noise_floor": floor,
                "ratio": rms / floor if floor else None,
                "unit": UNITS[n],
                "worst_positions": [int(i) for i in worst],
                "per_position": [float(v) for v in r],
            }
        )
    return rows


def default_candidates(positions: Positions, sensors: Sequence[str], t0_c: float) -> list[Term]:
    """Catalogue effects for the triads present (needs are checked when fitting)."""
    return [t for t in catalogue_terms(t0_c).values() if t.sensor in sensors]


def diagnose(
    positions: Positions,
    options: CalibrationOptions | None = None,
    candidates: Sequence[str] | None = None,
    max_rounds: int = 4,
) -> Diagnosis:
    """Rank candidate effects by how much of the misfit they explain (see module doc)."""
    opt = replace(options or CalibrationOptions(), method="lm")
    base = calibrate(positions, opt)
    sensors = base.problem.sensors
    pool = {t.name: t for t in default_candidates(positions, sensors, opt.t0_c)}
    pool.update({t.name: t for t in opt.plugin_terms if t.sensor in sensors})
    if candidates is not None:
        unknown = [c for c in candidates if c not in pool]
        if unknown:
            raise RecalInputError(f"unknown candidate effect(s): {', '.join(unknown)}")
        pool = {n: pool[n] for n in candidates}
    chosen = list(opt.effects)
    for name in chosen:
        pool.pop(name, None)
    n = base.problem.n_residuals
    fit0 = _fit(base, opt, chosen)
    ranked: list[Candidate] = []
    suggested: list[str] = []
    current = fit0
    for round_ in range(max_rounds):
        scored = [
            _score(current, base, opt, chosen + suggested, t, n, len(pool)) for t in pool.values()
        ]
        if round_ == 0:
            ranked = scored
        best = min((c for c in scored if c.significant), key=lambda c: c.delta_bic, default=None)
        if best is None:
            break
        suggested.append(best.effect)
        pool.pop(best.effect)
        current = _fit(base, opt, chosen + suggested)
    ranked.sort(key=lambda c: (not c.identifiable, np.nan_to_num(c.delta_bic, nan=np.inf)))
    _mark_similar(ranked)
    final_raw = current.problem.raw_residuals(current.theta[None])
    return Diagnosis(
        baseline=base,
        invariants=_invariant_rows(fit0),
        candidates=ranked,
        suggested_effects=suggested,
        baseline_effects=chosen,
        chi2_red=fit0.rss / max(n - fit0.rank, 1),
        final_chi2_red=current.rss / max(n - current.rank, 1),
        final_residuals={k: v[0] for k, v in final_raw.items()},
    )


def _score(
    current: Fit,
    base: CalibrationResult,
    opt: CalibrationOptions,
    effects: list[str],
    term: Term,
    n: int,
    n_candidates: int,
) -> Candidate:
    cand = Candidate(term.name, term.explanation, identifiable=True)
    try:
        fit = _fit(base, opt, effects + [term.name])
    except RecalInputError as exc:
        msg, src = str(exc), f"{base.problem.positions.source}: "
        cand.identifiable, cand.reason = False, msg[len(src) :] if msg.startswith(src) else msg
        return cand
    dk = fit.rank - current.rank
    if fit.verdict == "insufficient" or dk <= 0:
        cand.identifiable = False
        cand.reason = (
            "these positions cannot show it: the data pin it down no better than its typical size"
        )
        return cand
    cand.added_directions = dk
    cand.delta_bic = (fit.rss - current.rss) + dk * np.log(n)
    dof1 = max(n - fit.rank, 1)
    F = max(current.rss - fit.rss, 0.0) / dk / max(fit.rss / dof1, 1e-300)
    cand.p_value = float(stats.f.sf(F, dk, dof1))
    cand.significant = bool(cand.p_value < ALPHA / max(n_candidates, 1) and cand.delta_bic < 0)
    noise_power = (n - current.rank) if current.problem.noise_known else 0.0
    excess = current.rss - noise_power
    gain = current.rss - fit.rss
    cand.explained_fraction = float(np.clip(gain / excess, 0.0, 1.0)) if excess > 0 else 0.0
    raw = fit.problem.raw_residuals(fit.theta[None])
    cand.rms_after = {k: float(np.sqrt(np.mean(v[0] ** 2))) for k, v in raw.items()}
    cand.residuals_after = {k: v[0] for k, v in raw.items()}
    ctx = fit.problem.ctx
    cand.drivers = {k: np.asarray(ctx[k], dtype=float) for k in sorted(term.needs) if k in ctx}
    if not cand.drivers and "accel" in fit.problem.sensors:
        cand.drivers = {"specific_force_g": fit.problem._specific_force(fit.theta)}
    sl = fit.problem.layout.term_slices()[term.name]
    cand.parameters = dict(zip(term.params, map(float, fit.theta[sl]), strict=True))
    typical = fit.problem.layout.typical(fit.theta)
    rep = analyze(fit.problem, fit.theta, typical)
    cov, _ = covariance(fit.problem, fit.theta, typical[:, None] * rep.basis)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))[sl]
    cand.uncertainty = dict(zip(term.params, map(float, sd), strict=True))
    return cand


def _mark_similar(ranked: list[Candidate]) -> None:
    """Candidates whose improvement is within 2 BIC units of each other cannot be told apart."""
    ok = [c for c in ranked if c.identifiable and c.delta_bic < 0]
    for c in ok:
        c.similar_to = [o.effect for o in ok if o is not c and abs(o.delta_bic - c.delta_bic) < 2.0]
