"""Model discrepancy: where the fitted model fails, and which physical effect is missing.

:func:`diagnose` fits the model (seed terms plus any effects already chosen), compares each
invariant's residual with its noise floor, then tries every candidate effect of the catalogue
(docs/reference.md#effects) and of the user's plugins one at a time on top of it:

* ``delta_bic``: change of the Bayesian information criterion, chi^2 + k ln(n), where k counts
  the *observable* directions; negative means the effect earns its parameters.
* ``p_value``: F-test of the nested models (robust when the noise level is itself uncertain),
  nominal: it assumes independent residuals, which the gyro norm and the dot product of one
  window are not (they share its gyro noise).
* ``p_adjusted``: family-wise p-value over all candidates from a parametric bootstrap of the
  linearised fits with the residuals' real noise correlation (Westfall-Young min-p, 4000
  draws); ``significant``: ``p_adjusted < 0.01`` and ``delta_bic < 0``. On 197 clean sessions
  (12-36 random positions and the 24-position design, latitudes 0-70 deg) Bonferroni on the
  nominal F-test raised 4 false alarms (2.0 %), this rule 2 of 237 (0.8 %).
* ``explained_fraction``: share of the residual power above the noise floor that the effect
  removes (of all residual power when the noise is unknown).

All candidate fits share the baseline's residual weights, so their chi^2 values compare. The
greedy ``suggested_effects`` adds the best significant candidate and repeats until none is left.
A candidate the positions cannot show (e.g. a temperature term at constant temperature) is
listed with ``identifiable: false`` and the reason.

Two guards against the right residual for the wrong reason:

* ``core_shift``: how far adding the effect moves the seed coefficients (scale, bias,
  misalignment) in units of their 1-sigma in the current model, and ``trade_off``: the largest
  such shift with the correlation between that coefficient and the effect in the extended
  model. A large shift of a strongly correlated coefficient means the two trade off in these
  positions: the residual falls, but the coefficient takes whatever the effect's model says.
  The candidate then carries a ``warning`` and ``advice`` (what would separate them).
* ``trustworthy``: false when adding the effect moves any seed coefficient by more than
  ``CORE_SHIFT_SIGMA`` (3) of its current 1-sigma, whatever the correlation. The fall of chi^2
  then does not show the effect is right: an effect outside the catalogue with a similar
  signature (at one site a heading-dependent, e.g. magnetic, bias is a linear function of the
  gravity and Earth-rate directions) fits as well and puts the coefficients elsewhere. ``check``
  names those kinds of effect and how to decide (a plugin, held-out positions, an independent
  reference); the verdict says so and the diagnosis's own ``trustworthy`` (the final model
  against the baseline) is false. It does not say the effect is wrong: a true effect moves the
  coefficients too, and these data alone cannot tell the two apart.
* ``heldout_chi2_red``: leave-one-position-out chi^2 of the linearised fit over its expectation
  for a right model (1 when the model predicts the positions it did not see as well as the
  noise allows; above 1 when it fits the noise). It catches over-fitting, not a wrong effect
  with the same span (:func:`heldout_chi2_red`).
* ``confounded_with``: other candidates whose fitted signatures (the change each makes to the
  whitened residual) are correlated, with the correlation and the evidence ratio
  exp(-(BIC_other - BIC_self)/2); ``similar_to`` keeps those above 0.9 (cannot be told apart).

The baseline is never refused for its design at the solution: a missing effect can drag the
fit into a degenerate valley (the gyro-only norm fit has one at infinite scale, where every rate
collapses onto a constant vector of norm Omega). Such a fit is recognised by its rank falling
at the solution, and the baseline is then re-fitted from the candidates' non-degenerate
solutions. ``verdict`` says plainly when the residual stays above the noise floor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from recal.errors import RecalInputError
from recal.model.error_model import ParameterLayout
from recal.model.plugins import bind_context, site_context, values_by_term
from recal.model.positions import Positions
from recal.model.terms import Term, catalogue_terms
from recal.solve.calibrate import (
    UNITS,
    CalibrationOptions,
    CalibrationResult,
    blind_gyro,
    blind_gyro_models,
    build_models,
    calibrate,
)
from recal.solve.lm import covariance, solve_lm
from recal.solve.observability import analyze, jacobian
from recal.solve.problem import Problem

ALPHA = 0.01
#: Share of the excess misfit by which another candidate must explain more to be named as the
#: one that explains it better.
BETTER = 0.1


@dataclass
class Fit:
    """One model fitted with fixed residual weights."""

    effects: tuple[str, ...]
    problem: Problem
    theta: np.ndarray
    rank: int
    rss: float  # sum of squared whitened residuals (chi^2)
    verdict: str
    sd: np.ndarray | None = None  # 1-sigma per parameter at the solution (NaN where held)
    cov: np.ndarray | None = None  # covariance at the solution
    degenerate: bool = False  # the rank fell at the solution (a degenerate valley)
    jac: np.ndarray | None = None  # whitened Jacobian at the solution, observable directions
    transform: np.ndarray | None = None  # (D, k) parameter change per unit of those directions

    def residual(self) -> np.ndarray:
        return self.problem.residuals(self.theta[None])[0]


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
    #: seed coefficient -> shift in units of its current 1-sigma (largest three)
    core_shift: dict[str, float] = field(default_factory=dict)
    #: {"coefficient", "shift_sigma", "correlation"} of the largest shift, or None
    trade_off: dict[str, Any] | None = None
    warning: str = ""
    advice: str = ""
    #: [{"effect", "signature_correlation", "evidence_ratio", "advice"}]
    confounded_with: list[dict[str, Any]] = field(default_factory=list)
    #: False when the effect moves a seed coefficient by more than CORE_SHIFT_SIGMA (module doc)
    trustworthy: bool = True
    #: what shares the effect's signature and how to check it ('' when trustworthy)
    check: str = ""
    #: leave-one-position-out chi^2 over its expectation, with the effect (module doc)
    heldout_chi2_red: float = float("nan")
    #: the best-ranked candidate that explains more of the misfit than this one ('' if none)
    explained_better_by: str = ""
    #: change of the whitened residual the effect makes (for the confounding measure)
    signature: np.ndarray | None = None
    needs: frozenset[str] = frozenset()
    #: family-wise p-value from the parametric bootstrap (module doc)
    p_adjusted: float = float("nan")
    jac: np.ndarray | None = None
    #: Per-position raw residual of each invariant with the effect added (for the report's
    #: charts; not in the JSON).
    residuals_after: dict[str, np.ndarray] = field(default_factory=dict)
    #: What drives the effect, per position: its context columns (temperature_c,
    #: temperature_rate_c_per_h, time_h, specific_force_g (M, 3)); for an effect of the input
    #: itself (no context), the specific force when the accel is calibrated. Not in the JSON.
    drivers: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def disagreement(self) -> str:
        """Why delta BIC and the p-value disagree on this candidate ('' when they agree)."""
        if not (np.isfinite(self.delta_bic) and np.isfinite(self.p_adjusted)):
            return ""
        by_bic, by_p = self.delta_bic < 0, self.p_adjusted < ALPHA
        if by_bic and not by_p:
            head = (
                f"delta BIC favours {self.effect} ({self.delta_bic:.1f}: chi2 falls against the "
                f"window noise) but its family-wise p ({self.p_adjusted:.2g}) is not below "
                f"{ALPHA:g}: the F-test weighs the fall against the misfit left after the effect "
                "and against the number of effects tried"
            )
            if self.explained_fraction < 0.5:
                share = (
                    "under 1%"
                    if self.explained_fraction < 0.01
                    else f"{self.explained_fraction:.0%}"
                )
                other = (
                    f"a misfit another effect explains better ({self.explained_better_by})"
                    if self.explained_better_by
                    else "a misfit no candidate explains (see the verdict)"
                )
                return (
                    f"{head}; it explains only {share} of the excess, so it takes a share of "
                    f"{other}; not significant"
                )
            return f"{head}; a fall this size is what chance gives one of many effects tried"
        if by_p and not by_bic:
            return (
                f"the residual falls more than noise explains (p {self.p_adjusted:.2g}) but not "
                f"by enough to pay for {self.effect}'s {self.added_directions} parameter(s) "
                f"(delta BIC {self.delta_bic:+.1f}): probably real but small; more positions, or a "
                "wider swing of its driving variable, decide"
            )
        return ""

    def to_json_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        return {
            "effect": self.effect,
            "delta_bic": num(self.delta_bic),
            "p_value": num(self.p_value),
            "p_adjusted": num(self.p_adjusted),
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
            "core_shift": self.core_shift,
            "trade_off": self.trade_off,
            "warning": self.warning,
            "advice": self.advice,
            "confounded_with": self.confounded_with,
            "disagreement": self.disagreement,
            "trustworthy": self.trustworthy,
            "check": self.check,
            "heldout_chi2_red": num(self.heldout_chi2_red),
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
    verdict: str = ""
    model_fails: bool = False
    #: the model ladder: baseline, then each suggested effect added in turn
    ladder: list[dict[str, Any]] = field(default_factory=list)
    #: variable -> correlation with the final whitened residual (|r| largest first)
    residual_correlations: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: largest misfit with the suggested effects (:func:`worst_windows`), 0-based rows
    worst_positions: list[int] = field(default_factory=list)
    worst_slews: list[dict[str, int]] = field(default_factory=list)
    #: False when the suggested effects move a seed coefficient by more than CORE_SHIFT_SIGMA
    #: of its baseline 1-sigma: their coefficients are not better than the baseline's until
    #: checked (``warning`` says how)
    trustworthy: bool = True
    warning: str = ""
    #: seed coefficient -> shift from the baseline to the suggested model, baseline 1-sigma
    core_shift: dict[str, float] = field(default_factory=dict)

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "model_fails": self.model_fails,
            "trustworthy": self.trustworthy,
            "warning": self.warning,
            "core_shift": self.core_shift,
            "worst_positions": self.worst_positions,
            "worst_slews": self.worst_slews,
            "indexing": INDEXING,
            "ladder": self.ladder,
            "residual_correlations": self.residual_correlations,
            "notes": self.notes,
            "invariants": self.invariants,
            "candidates": [c.to_json_dict() for c in self.candidates],
            "suggested_effects": self.suggested_effects,
            "baseline_effects": self.baseline_effects,
            "chi2_red": _finite(self.chi2_red),
            "chi2_red_with_suggested": _finite(self.final_chi2_red),
            "noise_known": self.baseline.problem.noise_known,
            "noise_model": self.baseline.noise_model or None,
            "method": "LM fits with the baseline's residual weights; F-test and BIC per "
            "candidate; confounding from the correlation of fitted signatures",
            "alpha": ALPHA,
        }


def _finite(v: float) -> float | None:
    """JSON has no NaN: an undefined figure is null."""
    return float(v) if np.isfinite(v) else None


#: Singular value (whitened, per typical change) above which diagnose fits a direction. Lower
#: than calibrate's INFO_MIN = 1: an effect many times its typical size shows along a direction
#: the data pin down worse than that typical size (a scale-factor temperature coefficient of
#: 1e-4/degC against a typical 1e-5), and the F-test, not the prior size, must judge it.
FIT_INFO_MIN = 0.1


def _fit(
    base: CalibrationResult,
    opt: CalibrationOptions,
    effects: Sequence[str],
    start: dict[str, np.ndarray] | None = None,
    refit: bool = True,
) -> Fit:
    """Fit the model with ``effects`` on the baseline's positions, prior and residual weights,
    from ``start`` (term name -> values; default the baseline's solution), with the covariance
    and the rank at the solution."""
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
    if blind_gyro(base.problem.models):  # effects sized for a MEMS gyro, as calibrate's terms
        prior = values_by_term(base.layout, base.theta_prior)
        th = np.concatenate([np.asarray(prior.get(t.name, t.neutral), float)
                             for m in models for t in m.terms])  # fmt: skip
        models = blind_gyro_models(models, ParameterLayout(models), th)
    layout = ParameterLayout(models)
    start = start if start is not None else values_by_term(base.layout, base.theta)
    theta0 = np.concatenate(
        [np.asarray(start.get(t.name, t.neutral), float) for m in models for t in m.terms]
    )
    b = base.problem  # the baseline's slews and known rotations, so every fit sees the same data
    problem = Problem.build(positions, models, opt.latitude_deg, opt.height_m, theta0,
                            slews=b.slews, slew_earth_rate=b.slew_earth_rate,
                            known_rotations=b.known_rotations,
                            slew_excess_rad=b.slew_excess_rad)  # fmt: skip
    # the baseline's closed turns (decided at its prior), not decided again at this start
    problem = replace(problem, closed_turns=b.closed_turns, turn_candidates=b.turn_candidates)
    problem = problem.with_sigma(b.sigma, b.sigma_source)
    if b.wander is not None:  # the baseline's bias wander is part of the noise every fit sees
        problem = problem.with_wander(b.wander, theta0)
    typical = layout.typical(theta0)
    report = analyze(problem, theta0, typical, info_min=FIT_INFO_MIN)
    if report.verdict == "insufficient":
        return Fit(tuple(effects), problem, theta0, report.rank, float("nan"), report.verdict)
    theta = solve_lm(problem, theta0, typical[:, None] * report.basis).theta if refit else theta0
    r = problem.residuals(theta[None])[0]
    at = analyze(problem, theta, typical, info_min=FIT_INFO_MIN)
    cov, _ = covariance(problem, theta, typical[:, None] * at.basis)
    sd = np.where(at.estimated, np.sqrt(np.clip(np.diag(cov), 0, None)), np.nan)
    T = typical[:, None] * at.basis
    # degenerate: directions vanish structurally at the solution (not a weak direction that
    # crosses FIT_INFO_MIN as theta moves)
    degenerate = refit and _structural_rank(problem, theta, typical) < _structural_rank(
        problem, theta0, typical
    )
    return Fit(tuple(effects), problem, theta, report.rank, float(r @ r), report.verdict,
               sd, cov, degenerate=degenerate, jac=jacobian(problem, theta, T.T),
               transform=T)  # fmt: skip


def _structural_rank(problem: Problem, theta: np.ndarray, typical: np.ndarray) -> int:
    return analyze(problem, theta, typical, info_min=0.0).rank


def _invariant_rows(fit: Fit) -> list[dict[str, Any]]:
    raw = fit.problem.raw_residuals(fit.theta[None])
    rows = []
    for n in fit.problem.invariant_names:
        r = raw[n][0]
        known = fit.problem.noise_known_for(n)
        floor = float(np.sqrt(np.mean(fit.problem.sigma[n] ** 2))) if known else None
        rms = float(np.sqrt(np.mean(r**2)))
        # a slew has two residuals and a known rotation three: rank what they belong to, 0-based
        key, owner = _owners(fit.problem, n)
        score = np.bincount(owner, weights=(r / fit.problem.sigma[n]) ** 2)
        rows.append(
            {
                "name": n,
                "rms": rms,
                "noise_floor": floor,
                "ratio": rms / floor if floor else None,
                "unit": UNITS[n],
                key: [int(i) for i in np.argsort(-score, kind="stable")[:3] if score[i] > 0],
                "per_position": [float(v) for v in r],
            }
        )
    return rows


#: Invariants with one residual per position, in position order.
PER_POSITION = frozenset({"gyro_norm", "accel_norm", "dot"})


def _owners(problem: Problem, name: str) -> tuple[str, np.ndarray]:
    """What each residual of invariant ``name`` belongs to: (JSON key, 0-based index per
    residual) -- a position, a slew (two residuals; a closed turn is one of its slews) or a
    known rotation (three)."""
    k = problem.n_of(name)
    if name in PER_POSITION:  # a triad's invariants may skip the windows it was not still in
        rows = getattr(problem, "rows_of", None)
        return "worst_positions", np.arange(k) if rows is None else np.asarray(rows(name))
    if name == "slew":
        return "worst_slews", np.repeat(np.arange(k // 2), 2)
    if name == "closure" and getattr(problem, "closed_turns", None) is not None:
        return "worst_slews", np.asarray(problem.closed_turns.index, dtype=int)
    if name == "rotation":
        return "worst_rotations", np.repeat(np.arange(k // 3), 3)
    return f"worst_{name}", np.arange(k)


#: How diagnose numbers positions and slews in its text and JSON.
INDEXING = "0-based rows of the positions file (slews: 0-based, slew k joins its two windows)"


def worst_windows(fit: Fit, k: int = 3) -> tuple[list[int], list[dict[str, int]]]:
    """The ``k`` positions (0-based rows) with the largest whitened misfit summed over the
    per-position invariants, and the ``k`` slews with the largest misfit ({"slew", "from_row",
    "to_row"}), largest first and each named once."""
    p = fit.problem
    w = fit.residual()
    per_pos = np.zeros(p.M)
    per_slew = np.zeros(len(p.slews) if p.slews is not None else 0)
    start = 0
    for n in p.invariant_names:
        rows = w[start : start + p.n_of(n)]
        start += p.n_of(n)
        key, owner = _owners(p, n)
        if key == "worst_positions":
            per_pos += np.bincount(owner, weights=rows**2, minlength=p.M)
        elif key == "worst_slews":
            per_slew += np.bincount(owner, weights=rows**2, minlength=per_slew.size)
    positions = [int(i) for i in np.argsort(-per_pos, kind="stable")[:k]]
    slews = [
        {"slew": int(i), "from_row": int(p.slews.first[i]), "to_row": int(p.slews.second[i])}
        for i in np.argsort(-per_slew, kind="stable")[:k]
    ]
    return positions, slews


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
    opt = replace(options or CalibrationOptions(), method="lm", refuse_at_solution=False)
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
    notes: list[str] = []
    fit0 = _fit(base, opt, chosen)
    if fit0.degenerate or base.observability.verdict == "insufficient":
        fit0 = _rescue(base, opt, chosen, list(pool), fit0, notes)
    if fit0.rank != base.observability.rank and np.isfinite(base.chi2_red) and n > fit0.rank:
        notes.append(
            f"the baseline here fits {fit0.rank} directions and recal calibrate "
            f"{base.observability.rank} (diagnose fits directions the data pin down to "
            f"{FIT_INFO_MIN:g} of their typical change, calibrate to 1), so its chi2_red "
            f"({fit0.rss / (n - fit0.rank):.3g}) differs from calibrate's ({base.chi2_red:.3g})"
        )
    wander = (base.noise_model or {}).get("wander")
    if wander:
        notes.append(
            "wander first: the windows share a bias wander (recal.solve.wander; "
            + _wander_summary(wander)
            + "), which explains part of the misfit without any effect; every candidate is "
            "scored against the noise with it (a slow drift in time is wander, not an effect, "
            "unless an effect explains it better)"
        )
    ranked: list[Candidate] = []
    suggested: list[str] = []
    picked: list[Candidate] = []  # each suggestion as scored against the model it joined
    current = fit0
    ladder = [_rung("baseline", "", current, None, n)]
    for round_ in range(max_rounds):
        scored = [
            _score(current, base, opt, chosen + suggested, t, n, len(pool)) for t in pool.values()
        ]
        _family_pvalues(current, scored, n, np.random.default_rng(opt.seed + round_))
        if round_ == 0:
            ranked = scored
        best = min((c for c in scored if c.significant), key=lambda c: c.delta_bic, default=None)
        if best is None:
            break
        suggested.append(best.effect)
        picked.append(best)
        pool.pop(best.effect)
        start = values_by_term(current.problem.layout, current.theta)
        previous, current = current, _fit(base, opt, chosen + suggested, start=start)
        ladder.append(_rung(f"+{best.effect}", best.effect, current, previous, n))
    ranked.sort(key=lambda c: (not c.identifiable, np.nan_to_num(c.delta_bic, nan=np.inf)))
    for c in ranked:  # for the disagreement note: who explains this misfit clearly better
        c.explained_better_by = next((o.effect for o in ranked if o.identifiable and
                                      o.explained_fraction > c.explained_fraction + BETTER), "")  # fmt: skip
    _confounding(ranked)
    final_raw = current.problem.raw_residuals(current.theta[None])
    d = Diagnosis(
        baseline=base,
        invariants=_invariant_rows(fit0),
        candidates=ranked,
        suggested_effects=suggested,
        baseline_effects=chosen,
        chi2_red=fit0.rss / max(n - fit0.rank, 1),
        final_chi2_red=current.rss / max(n - current.rank, 1),
        final_residuals={k: v[0] for k, v in final_raw.items()},
        ladder=ladder,
        notes=notes,
    )
    _trust(d, fit0, current, picked)
    _conclude(d, current, n)
    return d


def _rescue(
    base: CalibrationResult,
    opt: CalibrationOptions,
    chosen: list[str],
    pool: list[str],
    fit0: Fit,
    notes: list[str],
) -> Fit:
    """A baseline out of a degenerate valley: the baseline model re-fitted from the seed
    coefficients of every candidate's non-degenerate fit; the best such fit, else ``fit0``."""
    starts = [values_by_term(base.layout, base.theta_prior)]
    for name in pool:
        try:
            f = _fit(
                base, opt, chosen + [name], start=values_by_term(base.layout, base.theta_prior)
            )
        except RecalInputError:
            continue
        if np.isfinite(f.rss) and not f.degenerate:
            starts.append(values_by_term(f.problem.layout, f.theta))
    fits = [_fit(base, opt, chosen, start=s) for s in starts]
    good = [f for f in fits if np.isfinite(f.rss) and not f.degenerate]
    if good:
        notes.append(
            "the baseline fit fell into a degenerate solution (the rank falls at the solution, "
            "e.g. scale factors running away); it was re-fitted from the candidates' solutions"
        )
        return min(good, key=lambda f: f.rss)
    # The baseline model has no plausible optimum (only the degenerate valley): judge it where
    # the candidates' plausible fits put the seed coefficients, without the effect.
    held = [_fit(base, opt, chosen, start=s, refit=False) for s in starts[1:]]
    held = [f for f in held if np.isfinite(f.rss) and not f.degenerate]
    if not held:
        notes.append("the baseline fit is degenerate (its rank falls at the solution) from "
                     "every start, and so is every candidate's: the model fails these data")  # fmt: skip
        return fit0
    notes.append(
        "the baseline model has no plausible fit: from every start it runs into a degenerate "
        "solution (scale factors running away); it is judged at the seed coefficients of the "
        "candidates' fits with the effect removed, which can only overstate its misfit"
    )
    return min(held, key=lambda f: f.rss)


def _rung(label: str, effect: str, fit: Fit, previous: Fit | None, n: int) -> dict[str, Any]:
    """One step of the model ladder: chi2 ratio per invariant (RMS / noise floor) and the
    change of BIC from the step before."""
    raw = fit.problem.raw_residuals(fit.theta[None])
    ratio = {}
    for k, v in raw.items():
        if fit.problem.noise_known_for(k):
            floor = float(np.sqrt(np.mean(fit.problem.sigma[k] ** 2)))
            ratio[k] = float(np.sqrt(np.mean(v[0] ** 2)) / floor)
    bic = fit.rss + fit.rank * np.log(n)
    step = None if previous is None else bic - (previous.rss + previous.rank * np.log(n))
    return {
        "model": label,
        "effect": effect,
        # no redundancy: the residual is zero by construction, so neither figure means anything
        "chi2_red": _finite(fit.rss / (n - fit.rank)) if n > fit.rank else None,
        "rms_over_floor": ratio,
        "delta_bic": None if step is None else _finite(step),
        "heldout_chi2_red": _finite(heldout_chi2_red(fit)) if n > fit.rank else None,
        "directions": fit.rank,
    }


def _conclude(d: Diagnosis, final: Fit, n: int) -> None:
    """The verdict: fits to the floor, or the model still fails (and where, and with what)."""
    dof = max(n - final.rank, 1)
    d.residual_correlations = _residual_correlations(final, d.baseline)
    d.worst_positions, d.worst_slews = worst_windows(final)
    added = ", ".join(d.suggested_effects)
    if n <= final.rank:  # the fit zeroes every residual: "at the floor" would say nothing
        d.verdict = (
            f"exactly determined: {n} invariant equations for {final.rank} observable "
            "directions, so the residual is zero whatever the model and cannot show whether an "
            "effect is missing; add positions (or orientations) to check the model"
        )
        if not d.suggested_effects:  # chi2_red of a fit with no redundancy is undefined
            d.chi2_red = d.final_chi2_red = float("nan")
        return
    if not final.problem.noise_known:
        d.verdict = (
            f"suggested: {added} (chi2_red {d.chi2_red:.3g} -> {d.final_chi2_red:.3g})"
            if added
            else "no candidate effect is significant"
        ) + "; the window noise is unknown, so whether the residual reaches the floor is unknown"
        d.verdict += f"; {d.warning}" if d.warning else ""
        return
    p_fit = float(stats.chi2.sf(final.rss, dof))
    d.model_fails = p_fit < ALPHA
    traded = [c.effect for c in d.candidates if c.effect in d.suggested_effects and c.warning]
    caveat = (
        f"; but {', '.join(traded)} trades off with the seed coefficients (see the warning): "
        "the residual may fall for the wrong reason"
        if traded
        else ""
    ) + (f"; {d.warning}" if d.warning else "")
    wander = (d.baseline.noise_model or {}).get("wander")
    if not d.model_fails:
        d.verdict = (
            f"with {added} the residual is at the noise floor (chi2_red {d.chi2_red:.3g} -> "
            f"{d.final_chi2_red:.3g})"
            if added
            else (
                "the misfit is bias wander between the windows ("
                + _wander_summary(wander)
                + f"), not a missing effect: with it the model fits to the noise floor "
                f"(chi2_red {d.chi2_red:.3g})"
                if wander
                else f"the model fits to the noise floor (chi2_red {d.chi2_red:.3g}); no effect "
                "missing"
            )
        ) + caveat
        return
    per = ", ".join(map(str, d.worst_positions))
    if d.worst_slews:
        per += "; worst slews " + ", ".join(
            f"{s['slew']} (rows {s['from_row']}->{s['to_row']})" for s in d.worst_slews
        )
    corr = ", ".join(f"{k} (r = {v:+.2f})" for k, v in list(d.residual_correlations.items())[:3])
    model = f"with {added}" if added else "with the seed model"
    d.verdict = (
        f"the model still fails: chi2_red {d.final_chi2_red:.3g} {model} (p = {p_fit:.2g} "
        "against the noise floor) and no candidate explains the rest; worst positions "
        f"(0-based rows) {per}"
        + (f"; the residual correlates with {corr}" if corr else "")
        + "; an effect outside the catalogue may be missing: write it as a --plugin"
        + (f"; {d.warning}" if d.warning else "")
    )


def _wander_summary(wander: dict[str, Any]) -> str:
    parts = []
    for s in ("gyro", "accel"):
        if s in wander:
            taus = [v for v in wander[s]["tau_s"] if v is not None]
            tau = f", tau {max(taus) / 3600:.3g} h" if taus else ""
            parts.append(f"{s} sigma {max(wander[s]['sigma']):.3g}{tau}")
    return "; ".join(parts)


def _residual_correlations(fit: Fit, base: CalibrationResult) -> dict[str, float]:
    """Pearson r of each invariant's per-position whitened residual with the variables that
    could drive a missing effect (temperature, its rate, time, the gravity direction)."""
    pos = fit.problem.positions
    cols = pos.columns
    drivers: dict[str, np.ndarray] = {}
    for k in ("temperature_c", "temperature_rate_c_per_h"):
        if k in cols:
            drivers[k] = np.asarray(cols[k], float)
    if "start_s" in cols and "end_s" in cols:
        drivers["time_h"] = 0.5 * (cols["start_s"] + cols["end_s"]) / 3600.0
    site = site_context(pos, values_by_term(base.layout, base.theta), fit.problem.latitude_deg,
                        fit.problem.height_m)  # fmt: skip
    for k in ("gravity_direction", "north"):
        if k in site:
            drivers.update({f"{k}_{a}": site[k][:, j] for j, a in enumerate("xyz")})
    raw = fit.problem.raw_residuals(fit.theta[None])
    out: dict[str, float] = {}
    for inv, v in raw.items():
        if inv not in ("gyro_norm", "accel_norm", "dot"):
            continue
        w = v[0] / fit.problem.sigma[inv]
        rows = fit.problem.rows_of(inv)
        for k, x in drivers.items():
            x = x[rows]
            if np.ptp(x) > 0 and np.ptp(w) > 0:
                out[f"{inv} vs {k}"] = float(np.corrcoef(w, x)[0, 1])
    return dict(sorted(out.items(), key=lambda kv: -abs(kv[1])))


#: Shift of a seed coefficient, in its current 1-sigma, and correlation with the effect above
#: which the candidate carries a trade-off warning.
SHIFT_WARN_SIGMA = 5.0
#: Shift of a seed coefficient, in its current 1-sigma, beyond which the fit of an effect is not
#: trusted without a check (``trustworthy``: false), whatever the correlation.
CORE_SHIFT_SIGMA = 3.0
CORRELATION_WARN = 0.9
#: Signature correlation above which two candidates are listed as confounded / the same.
CONFOUNDED = 0.7
SAME = 0.9


def _score(
    current: Fit,
    base: CalibrationResult,
    opt: CalibrationOptions,
    effects: list[str],
    term: Term,
    n: int,
    n_candidates: int,
) -> Candidate:
    cand = Candidate(term.name, term.explanation, identifiable=True, needs=frozenset(term.needs))
    try:
        fit = _fit(base, opt, effects + [term.name], start=values_by_term(
            current.problem.layout, current.theta))  # fmt: skip
    except RecalInputError as exc:
        msg, src = str(exc), f"{base.problem.positions.source}: "
        cand.identifiable, cand.reason = False, msg[len(src) :] if msg.startswith(src) else msg
        return cand
    dk = fit.rank - current.rank
    if fit.degenerate:
        cand.identifiable = False
        cand.reason = (
            "its fit is degenerate (the rank falls at the solution: coefficients run away), so "
            "it does not describe these data"
        )
        return cand
    if fit.verdict == "insufficient" or dk <= 0:
        cand.identifiable = False
        cand.reason = _why_not_shown(current, fit, term)
        return cand
    cand.added_directions = dk
    cand.delta_bic = (fit.rss - current.rss) + dk * np.log(n)
    dof1 = max(n - fit.rank, 1)
    F = max(current.rss - fit.rss, 0.0) / dk / max(fit.rss / dof1, 1e-300)
    cand.p_value = float(stats.f.sf(F, dk, dof1))
    cand.jac = fit.jac
    noise_power = (n - current.rank) if current.problem.noise_known else 0.0
    excess = current.rss - noise_power
    gain = current.rss - fit.rss
    cand.explained_fraction = float(np.clip(gain / excess, 0.0, 1.0)) if excess > 0 else 0.0
    cand.signature = current.residual() - fit.residual()
    raw = fit.problem.raw_residuals(fit.theta[None])
    cand.rms_after = {k: float(np.sqrt(np.mean(v[0] ** 2))) for k, v in raw.items()}
    cand.residuals_after = {k: v[0] for k, v in raw.items()}
    # the problem's context, and what a plugin term was bound to (site quantities, columns)
    bound = next(t for m in fit.problem.models for t in m.terms if t.name == term.name)
    ctx = {**fit.problem.ctx, **getattr(bound, "extra", {})}
    m = fit.problem.M
    cand.drivers = {k: np.asarray(ctx[k], dtype=float) for k in sorted(term.needs)
                    if k in ctx and np.shape(ctx[k])[:1] == (m,)}  # fmt: skip
    if not cand.drivers and "accel" in fit.problem.sensors:
        cand.drivers = {"specific_force_g": fit.problem._specific_force(fit.theta)}
    sl = fit.problem.layout.term_slices()[term.name]
    cand.parameters = dict(zip(term.params, map(float, fit.theta[sl]), strict=True))
    assert fit.sd is not None
    cand.uncertainty = dict(zip(term.params, map(float, fit.sd[sl]), strict=True))
    _trade_off(cand, current, fit, sl)
    cand.heldout_chi2_red = heldout_chi2_red(fit)
    return cand


#: Parametric-bootstrap draws of the family-wise null distribution.
NULL_DRAWS = 4000


def noise_correlation(problem: Problem, theta: np.ndarray) -> np.ndarray:
    """(R, R) correlation of the whitened residuals from the window noise. The gyro norm and
    the dot product of one position share that window's gyro noise (and the accel norm and the
    dot its accel noise): corr = u_w' S_g f / (sd_norm sd_dot). At high latitude, where Earth
    rate and gravity are nearly parallel, it approaches 1, and a chi^2 that counts both as
    independent overstates the evidence for a gyro effect."""
    R = problem.n_residuals
    C = np.eye(R)
    names = problem.invariant_names
    if "dot" not in names or not problem.noise_known:
        return C
    pos = problem.positions
    x = problem.physical(theta[None])
    w, f = x["gyro"][0], x["accel"][0]
    sl = problem.layout.term_slices()
    sg = pos.std_of_mean("gyro") / np.abs(theta[sl["gyro.scale"]])  # (M, 3) input units
    sa = pos.std_of_mean("accel") / np.abs(theta[sl["accel.scale"]])
    uw = w / np.linalg.norm(w, axis=1, keepdims=True)
    uf = f / np.linalg.norm(f, axis=1, keepdims=True)
    var_g = np.sum((uw * sg) ** 2, axis=1)
    var_a = np.sum((uf * sa) ** 2, axis=1)
    var_d = np.sum((f * sg) ** 2 + (w * sa) ** 2, axis=1)
    rho_g = np.sum(uw * f * sg**2, axis=1) / np.sqrt(var_g * var_d)
    rho_a = np.sum(uf * w * sa**2, axis=1) / np.sqrt(var_a * var_d)
    # norms and dot come first; the gyro's (and the dot) leave out accelerometer-only windows
    start = dict(zip(names, np.cumsum([0, *(problem.n_of(n) for n in names[:-1])]), strict=True))
    dot_rows = problem.rows_of("dot")
    for inv, rho in (("gyro_norm", rho_g), ("accel_norm", rho_a)):
        if inv not in start:
            continue
        m = np.searchsorted(problem.rows_of(inv), dot_rows)  # each dot row in inv's rows
        i, j = start[inv] + m, start["dot"] + np.arange(dot_rows.shape[0])
        C[i, j] = C[j, i] = rho[dot_rows]
    return C


def _span(J: np.ndarray, k: int) -> np.ndarray:
    """Orthonormal basis of the k leading left singular directions of J."""
    U, _, _ = np.linalg.svd(J, full_matrices=False)
    return U[:, :k]


def _family_pvalues(
    current: Fit, scored: list[Candidate], n: int, rng: np.random.Generator
) -> None:
    """Family-wise p-values by a parametric bootstrap of the linearised fits (Westfall-Young
    min-p): noise with the residuals' real correlation (:func:`noise_correlation`) is drawn,
    every candidate's F statistic computed as diagnose computes it, and a candidate's
    ``p_adjusted`` is the share of draws in which the smallest nominal p of all candidates is
    below its own. Significant: ``p_adjusted < ALPHA`` and ``delta_bic < 0``. It replaces a
    Bonferroni cut whose F-test assumed independent residuals."""
    ok = [c for c in scored if c.identifiable and c.jac is not None and np.isfinite(c.p_value)]
    if not ok or current.jac is None:
        return
    C = noise_correlation(current.problem, current.theta)
    L = np.linalg.cholesky(C + 1e-9 * np.eye(len(C)))
    E = L @ rng.standard_normal((len(C), NULL_DRAWS))
    Q0 = _span(current.jac, current.rank)
    rss0 = np.sum((E - Q0 @ (Q0.T @ E)) ** 2, axis=0)
    null_p = []
    for c in ok:
        k = current.rank + c.added_directions
        Qc = _span(np.hstack([current.jac, c.jac]), k)
        rss1 = np.sum((E - Qc @ (Qc.T @ E)) ** 2, axis=0)
        dof1 = max(n - k, 1)
        F = np.maximum(rss0 - rss1, 0.0) / c.added_directions / np.maximum(rss1 / dof1, 1e-300)
        null_p.append(stats.f.sf(F, c.added_directions, dof1))
    min_p = np.min(null_p, axis=0)
    for c in ok:
        c.p_adjusted = float((1 + np.sum(min_p <= c.p_value)) / (1 + NULL_DRAWS))
        c.significant = bool(c.p_adjusted < ALPHA and c.delta_bic < 0)


def _why_not_shown(current: Fit, fit: Fit, term: Term) -> str:
    """Why the extended model has no new observable direction, from its Jacobian: the data do
    not see the effect at all, or they see it only along directions the current model's
    coefficients already span (then it cannot be separated from them in this design)."""
    layout = fit.problem.layout
    sl = layout.term_slices()[term.name]
    typical = layout.typical(fit.theta)
    idx = np.arange(layout.size)[sl]
    Je = jacobian(fit.problem, fit.theta, (typical[idx, None] * np.eye(layout.size)[idx]))
    seen = np.linalg.norm(Je, 2) if Je.size else 0.0
    if seen < FIT_INFO_MIN or current.jac is None or not current.jac.size:
        return (
            "these positions cannot show it: the data pin it down no better than its typical size"
        )
    # Je ~ J0 Z on the current model's observable directions; T Z is the coefficient change
    # that mimics one typical change of the effect, here per the coefficients' typical change
    Z, *_ = np.linalg.lstsq(current.jac, Je, rcond=None)
    names0 = current.problem.layout.names
    typ0 = current.problem.layout.typical(current.theta)
    weight = np.linalg.norm(current.transform @ Z, axis=1) / typ0
    top = [names0[i] for i in np.argsort(-weight)[:3] if weight[i] > 0.1]
    who = ", ".join(top) or "the coefficients already in the model"
    return (
        f"cannot be separated from {who} in this design: every direction the data show of it "
        "is already one of theirs (from the extended model's Jacobian)"
    )


def _core_indices(names: list[str]) -> list[int]:
    core = (".scale.", ".bias.", ".misalignment.")
    return [i for i, nm in enumerate(names) if nm.split(".", 1)[0] in ("gyro", "accel")
            and any(c in nm for c in core) and nm.count(".") == 2]  # fmt: skip


def _core_shift(
    names0: Sequence[str],
    theta0: np.ndarray,
    sd0: np.ndarray,
    names1: Sequence[str],
    theta1: np.ndarray,
    most: int = 3,
) -> dict[str, float]:
    """How far the seed coefficients (scale, bias, misalignment) move from one model (``names0``,
    ``theta0`` with 1-sigma ``sd0``) to another (``names1``, ``theta1``): coefficient -> shift in
    units of that 1-sigma, the ``most`` largest by size, largest first. A coefficient the other
    model lacks, or whose 1-sigma is not above 0 (NaN: held, or not to be compared), is left
    out."""
    where = {nm: j for j, nm in enumerate(names1)}
    shifts: dict[str, float] = {}
    for i in _core_indices(list(names0)):
        j = where.get(names0[i])
        if j is None or not sd0[i] > 0:
            continue
        shifts[names0[i]] = float((theta1[j] - theta0[i]) / sd0[i])
    top = sorted(shifts, key=lambda k: -abs(shifts[k]))[:most]
    return {k: shifts[k] for k in top}


def _trade_off(cand: Candidate, current: Fit, fit: Fit, sl: slice) -> None:
    """How far the effect moves the seed coefficients (in their current 1-sigma) and whether
    it trades off with them in the extended model (module doc)."""
    if current.sd is None or fit.cov is None:
        return
    names1 = fit.problem.layout.names
    shifts = _core_shift(current.problem.layout.names, current.theta,
                         np.where(np.isfinite(current.sd), current.sd, np.nan), names1, fit.theta)  # fmt: skip
    if not shifts:
        return
    cand.core_shift = shifts
    cov = fit.cov
    eff = np.arange(cov.shape[0])[sl]
    name = next(iter(shifts))
    j = names1.index(name)
    corr = _multiple_correlation(cov, j, eff)
    cand.trade_off = {"coefficient": name, "shift_sigma": shifts[name], "correlation": corr}
    if abs(shifts[name]) > CORE_SHIFT_SIGMA:
        cand.trustworthy = False
        cand.check = _shift_check(cand.effect, cand.needs, name, shifts[name])
    if abs(shifts[name]) >= SHIFT_WARN_SIGMA and abs(corr) >= CORRELATION_WARN:
        cand.advice = _core_advice(cand.needs, cand.effect)
        cand.warning = (
            f"adding {cand.effect} moves {name} by {abs(shifts[name]):.1f} sigma: they trade off "
            f"in these positions (multiple correlation {corr:.2f}), so the fit is only as right as the "
            f"effect's model; to separate them: {cand.advice}"
        )


DRIFT_NEEDS = frozenset({"temperature_c", "temperature_rate_c_per_h", "time_h"})


def _look_alikes(needs: frozenset[str]) -> str:
    """The kinds of effect outside the catalogue that share the signature of an effect with
    these drivers."""
    if needs & DRIFT_NEEDS:
        return (
            "another effect that follows temperature or time in the same way (out of the "
            "catalogue: a thermal gradient, hysteresis, a drift that is not linear in time)"
        )
    return (
        "an orientation-dependent effect out of the catalogue, such as a heading-dependent "
        "bias (a magnetic, e.g. Faraday, sensitivity: at one site the field in body axes is a "
        "linear function of the gravity and Earth-rate directions)"
    )


#: How to decide whether a large core shift is right (the same for every effect).
SHIFT_CHECKS = (
    "write the suspected effect as a --plugin and see which diagnose prefers and how the "
    "coefficients then move; hold out positions (repeat some, or a second session) and compare "
    "the predictions; or compare the moved coefficients with an independent reference (a "
    "turntable, --known-rotations, the accepted calibration)"
)


def _shift_check(effect: str, needs: frozenset[str], coefficient: str, shift: float) -> str:
    """Why a fit that moves ``coefficient`` by ``shift`` sigma needs a check, and which."""
    return (
        f"adding {effect} moves {coefficient} by {abs(shift):.1f} sigma (more than "
        f"{CORE_SHIFT_SIGMA:g}): the fall of chi2 does not show {effect} is right, since "
        f"{_look_alikes(needs)} would fit as well and move the coefficients elsewhere; before "
        f"using them: {SHIFT_CHECKS}"
    )


def _trust(d: Diagnosis, fit0: Fit, final: Fit, picked: Sequence[Candidate]) -> None:
    """The diagnosis's trust: how far the suggested effects together move the seed coefficients
    from the baseline (in its 1-sigma), and the warning when any moves by more than
    CORE_SHIFT_SIGMA."""
    if not picked or fit0.sd is None:
        return
    shifts = _core_shift(fit0.problem.layout.names, fit0.theta,
                         np.where(np.isfinite(fit0.sd), fit0.sd, np.nan),
                         final.problem.layout.names, final.theta)  # fmt: skip
    top = list(shifts)
    d.core_shift = shifts
    if not top or abs(shifts[top[0]]) <= CORE_SHIFT_SIGMA and all(c.trustworthy for c in picked):
        return
    d.trustworthy = False
    added = ", ".join(c.effect for c in picked)
    needs = frozenset().union(*(c.needs for c in picked))
    moved = ", ".join(f"{k} {abs(shifts[k]):.1f}" for k in top if abs(shifts[k]) > 1)
    d.warning = (
        f"NOT CONFIRMED: {added} moves the core coefficients by more than {CORE_SHIFT_SIGMA:g} "
        f"sigma ({moved} sigma), so these coefficients are not better than the seed model's "
        f"until checked: {_look_alikes(needs)} would fit as well and move them elsewhere; "
        f"check: {SHIFT_CHECKS}"
    )


def effects_check(result: CalibrationResult, options: CalibrationOptions) -> dict[str, Any] | None:
    """For a calibration whose model has effects beyond the seed terms: how far they moved the
    seed coefficients from a seed-model fit of the same positions (in that fit's 1-sigma), and
    whether the result may count as better than the seed model (``trustworthy``; the same rule
    as diagnose's). None without effects. Costs one more calibration."""
    effects = [e for e in options.effects if e in result.terms]
    if not effects:
        return None
    seed = calibrate(result.problem.positions, replace(options, effects=()))
    sd0 = np.concatenate([seed.uncertainty[n] for n in seed.layout.term_slices()])
    sd0 = np.where(seed.observability.estimated, sd0, np.nan)  # held: not compared
    shifts = _core_shift(seed.layout.names, seed.theta, sd0, result.layout.names, result.theta)
    top = list(shifts)
    trustworthy = not top or abs(shifts[top[0]]) <= CORE_SHIFT_SIGMA
    needs = frozenset().union(*(result.terms[e].needs for e in effects))
    warning = "" if trustworthy else (
        f"NOT CONFIRMED: {', '.join(effects)} moves the core coefficients by more than "
        f"{CORE_SHIFT_SIGMA:g} sigma from the seed model's fit ("
        + ", ".join(f"{k} {abs(shifts[k]):.1f}" for k in top if abs(shifts[k]) > 1)
        + f" sigma): not better than the seed model's coefficients until checked; "
        f"{_look_alikes(needs)} would fit as well; check: {SHIFT_CHECKS}"
    )  # fmt: skip
    return {"effects": effects, "trustworthy": trustworthy,
            "core_shift": shifts, "seed_chi2_red": _finite(seed.chi2_red),
            "warning": warning}  # fmt: skip


def heldout_chi2_red(fit: Fit) -> float:
    """Leave-one-position-out chi^2 of the linearised fit over its expectation for a right
    model: positions are left out one at a time (all their invariants; slews and known
    rotations always stay in), the fit is redone without them along the observable directions
    and their whitened residuals predicted. For a linear fit the deletion is exact,
    e_g = (I - H_gg)^-1 r_g with H the hat matrix, and E[e_g' e_g] = tr((I - H_gg)^-1) under
    the window noise; the ratio of the sums is 1 for a right model, above 1 when the model
    fits the noise. NaN without a Jacobian or with fewer than three positions."""
    if fit.jac is None or not fit.jac.size or fit.problem.M < 3:
        return float("nan")
    p = fit.problem
    group = np.concatenate(
        [_owners(p, n)[1] if n in PER_POSITION else np.full(p.n_of(n), -1)
         for n in p.invariant_names]
    )  # fmt: skip
    U, sv, _ = np.linalg.svd(fit.jac, full_matrices=False)
    Q = U[:, sv > sv[0] * 1e-10] if sv.size and sv[0] > 0 else U[:, :0]
    r = fit.residual()
    members = [np.flatnonzero(group == i) for i in range(p.M)]
    press = expected = 0.0
    for size in {len(m) for m in members} - {0}:  # positions with as many rows, batched
        rows = np.stack([m for m in members if len(m) == size])  # (G, size)
        Qg = Q[rows]  # (G, size, rank)
        A = np.eye(size)[None] - Qg @ np.swapaxes(Qg, 1, 2)
        Ainv = np.linalg.pinv(A, rcond=1e-10, hermitian=True)
        e = np.einsum("gij,gj->gi", Ainv, r[rows])
        press += float(np.sum(e * e))
        expected += float(np.trace(Ainv, axis1=1, axis2=2).sum())
    return press / expected if expected > 0 else float("nan")


def _multiple_correlation(cov: np.ndarray, j: int, eff: np.ndarray) -> float:
    """Multiple correlation of parameter ``j`` with the parameters ``eff`` (how much of j's
    uncertainty the effect explains): sqrt(c_je C_ee^-1 c_ej / c_jj), in [0, 1]."""
    c_je = cov[j, eff]
    C_ee = cov[np.ix_(eff, eff)]
    if cov[j, j] <= 0:
        return 0.0
    r2 = float(c_je @ np.linalg.pinv(C_ee, rcond=1e-12) @ c_je / cov[j, j])
    return float(np.sqrt(np.clip(r2, 0.0, 1.0)))


def _core_advice(needs: frozenset[str], effect: str) -> str:
    """What would separate an effect from the seed coefficients, by what drives it."""
    if needs & {"temperature_c", "temperature_rate_c_per_h"}:
        return "a temperature swing during the session (a cycle, not a ramp), positions repeated at several temperatures"
    if "time_h" in needs:
        return "repeat the first positions at the end of the session"
    if effect.endswith("scale_asymmetry"):
        return "positions with each axis both up and down"
    return (
        "a second site latitude (it changes the angle between gravity and Earth rate), or a "
        "design with more orientations about each axis"
    )


def _pair_advice(a: Candidate, b: Candidate) -> str:
    """What would tell two confounded candidates apart, by what drives them."""
    keys = a.needs | b.needs
    if {"temperature_c", "time_h"} <= keys or {"temperature_rate_c_per_h", "time_h"} <= keys:
        return "add a temperature swing (a cycle, not a ramp): temperature and time then differ"
    if {"temperature_c", "temperature_rate_c_per_h"} <= keys:
        return "hold some positions at steady temperature: level and rate then differ"
    if a.needs == b.needs and "temperature_c" in keys:
        return "a wider temperature range"
    return "more orientations, or a second site latitude"


def _confounding(ranked: list[Candidate]) -> None:
    """Correlation of the candidates' fitted signatures, evidence ratios and advice (module
    doc); replaces a hard cut on the BIC difference."""
    ok = [c for c in ranked if c.identifiable and c.signature is not None and c.delta_bic < 0]
    if len(ok) < 2:
        return
    S = np.array([c.signature for c in ok])
    norm = np.linalg.norm(S, axis=1)
    C = (S @ S.T) / np.maximum(np.outer(norm, norm), 1e-300)
    for i, c in enumerate(ok):
        for j, o in enumerate(ok):
            if i == j or abs(C[i, j]) < CONFOUNDED:
                continue
            ratio = float(np.exp(np.clip(-(o.delta_bic - c.delta_bic) / 2, -700, 700)))
            c.confounded_with.append(
                {
                    "effect": o.effect,
                    "signature_correlation": float(C[i, j]),
                    "evidence_ratio": ratio,
                    "advice": _pair_advice(c, o),
                }
            )
            if abs(C[i, j]) >= SAME:
                c.similar_to.append(o.effect)
