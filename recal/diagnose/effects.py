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
from dataclasses import replace

import numpy as np

# This module was split by idea (fit, candidates, trust, diagnosis); the names it defined stay
# importable from here (code, tests, docs and recal.diagnose's deprecated old names use them).
from recal.diagnose.candidates import (  # noqa: F401 - re-exported
    ALPHA,
    BETTER,
    CONFOUNDED,
    NULL_DRAWS,
    SAME,
    Candidate,
    against_noise,
    default_candidates,
    family_pvalues,
    mark_confounding,
    noise_correlation,
    score_candidates,
)
from recal.diagnose.diagnosis import Diagnosis, conclude, rung
from recal.diagnose.fit import (  # noqa: F401 - re-exported
    FIT_INFO_MIN,
    INDEXING,
    PER_POSITION,
    Fit,
    best_fit,
    fit_effects,
    heldout_chi2_red,
    invariant_rows,
    worst_windows,
)
from recal.diagnose.hypotheses import noise_fit
from recal.diagnose.lookalikes import lookalike_check
from recal.diagnose.shift import (  # noqa: F401 - re-exported
    CORE_SHIFT_SIGMA,
    CORRELATION_WARN,
    DRIFT_NEEDS,
    SHIFT_CHECKS,
    SHIFT_WARN_SIGMA,
)
from recal.diagnose.trust import effects_check, trust_diagnosis  # noqa: F401 - re-exported
from recal.errors import RecalInputError
from recal.model.plugins import values_by_term
from recal.model.positions import Positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from recal.solve.result import CalibrationResult


def diagnose(
    positions: Positions,
    options: CalibrationOptions | None = None,
    candidates: Sequence[str] | None = None,
    max_rounds: int = 4,
) -> Diagnosis:
    """Rank candidate effects by how much of the misfit they explain (see module doc)."""
    opt = replace(options or CalibrationOptions(), method="lm", refuse_at_solution=False)
    calibrated = calibrate(positions, opt)
    # Every model is fitted with independent windows; what the misfit holds beyond the windows'
    # noise (a wander, an independent excess) is asked of each model in turn
    # (recal.diagnose.hypotheses), never put into the baseline first.
    base = replace(calibrated, problem=calibrated.problem.with_wander(None, calibrated.theta))
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
    fit0 = fit_effects(base, opt, chosen)
    if fit0.degenerate or base.observability.verdict == "insufficient":
        fit0 = _rescue(base, opt, chosen, list(pool), fit0, notes)
    if fit0.rank != base.observability.rank and np.isfinite(base.chi2_red) and n > fit0.rank:
        notes.append(
            f"the baseline here fits {fit0.rank} directions and recal calibrate "
            f"{base.observability.rank} (diagnose fits directions the data pin down to "
            f"{FIT_INFO_MIN:g} of their typical change, calibrate to 1), so its chi2_red "
            f"({fit0.rss / (n - fit0.rank):.3g}) differs from calibrate's ({base.chi2_red:.3g})"
        )
    ranked: list[Candidate] = []
    suggested: list[str] = []
    picked: list[Candidate] = []  # each suggestion as scored against the model it joined
    current = fit0
    noise0 = noise = noise_fit(current)
    ladder = [rung("baseline", "", current, None, n, noise)]
    for round_ in range(max_rounds):
        scored = [
            score_candidates(current, base, opt, chosen + suggested, t, n, len(pool))
            for t in pool.values()
        ]
        family_pvalues(current, scored, n, np.random.default_rng(opt.seed + round_))
        against_noise(noise, scored, n, np.random.default_rng(opt.seed + 7 + round_))
        if round_ == 0:
            ranked = scored
        best = min((c for c in scored if c.significant), key=lambda c: c.delta_bic, default=None)
        if best is None:
            break
        suggested.append(best.effect)
        picked.append(best)
        pool.pop(best.effect)
        start = values_by_term(current.problem.layout, current.theta)
        previous, current = current, best_fit(base, opt, chosen + suggested, start)
        noise = noise_fit(current)
        ladder.append(rung(f"+{best.effect}", best.effect, current, previous, n, noise))
    ranked.sort(key=lambda c: (not c.identifiable, np.nan_to_num(c.delta_bic, nan=np.inf)))
    for c in ranked:  # for the disagreement note: who explains this misfit clearly better
        c.explained_better_by = next((o.effect for o in ranked if o.identifiable and
                                      o.explained_fraction > c.explained_fraction + BETTER), "")  # fmt: skip
    mark_confounding(ranked)
    final_raw = current.problem.raw_residuals(current.theta[None])
    d = Diagnosis(
        baseline=calibrated,
        invariants=invariant_rows(fit0),
        candidates=ranked,
        suggested_effects=suggested,
        baseline_effects=chosen,
        chi2_red=fit0.rss / max(n - fit0.rank, 1),
        final_chi2_red=current.rss / max(n - current.rank, 1),
        final_residuals={k: v[0] for k, v in final_raw.items()},
        ladder=ladder,
        notes=notes,
        noise=noise0,
        final_noise=noise,
    )
    trust_diagnosis(d, fit0, current, picked)
    lookalike_check(d, base, opt, chosen, current, picked)
    conclude(d, current, n, picked)
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
            f = fit_effects(
                base, opt, chosen + [name], start=values_by_term(base.layout, base.theta_prior)
            )
        except RecalInputError:
            continue
        if np.isfinite(f.rss) and not f.degenerate:
            starts.append(values_by_term(f.problem.layout, f.theta))
    fits = [fit_effects(base, opt, chosen, start=s) for s in starts]
    good = [f for f in fits if np.isfinite(f.rss) and not f.degenerate]
    if good:
        notes.append(
            "the baseline fit fell into a degenerate solution (the rank falls at the solution, "
            "e.g. scale factors running away); it was re-fitted from the candidates' solutions"
        )
        return min(good, key=lambda f: f.rss)
    # The baseline model has no plausible optimum (only the degenerate valley): judge it where
    # the candidates' plausible fits put the seed coefficients, without the effect.
    held = [fit_effects(base, opt, chosen, start=s, refit=False) for s in starts[1:]]
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
