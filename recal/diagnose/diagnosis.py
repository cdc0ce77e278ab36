"""The result of diagnose: :class:`Diagnosis`, its model ladder (:func:`rung`), its verdict
(:func:`conclude`) and the variables its final residual correlates with."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from recal.diagnose.candidates import ALPHA, Candidate
from recal.diagnose.fit import INDEXING, Fit, finite_or_none, heldout_chi2_red, worst_windows
from recal.diagnose.hypotheses import NoiseFit, describe
from recal.model.plugins import site_context, values_by_term
from recal.solve.result import CalibrationResult


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
    #: the baseline's misfit as noise (wander or independent excess), and the final model's
    #: (recal.diagnose.hypotheses)
    noise: NoiseFit | None = None
    final_noise: NoiseFit | None = None
    #: what explains the misfit: "effect", "wander", "excess", "nothing" (fits the floor) or
    #: "unexplained"; and the figures of the hypotheses compared (IC, lower is better)
    explanation: str = ""
    hypotheses: dict[str, Any] = field(default_factory=dict)
    #: the look-alike fitted in place of an orientation-driven gyro effect
    #: (recal.diagnose.lookalikes): its chi2, the F-test's p and where it puts the core
    lookalike: dict[str, Any] | None = None

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "explanation": self.explanation,
            "hypotheses": self.hypotheses,
            "model_fails": self.model_fails,
            "trustworthy": self.trustworthy,
            "warning": self.warning,
            "core_shift": self.core_shift,
            "lookalike": self.lookalike,
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
            "chi2_red": finite_or_none(self.chi2_red),
            "chi2_red_with_suggested": finite_or_none(self.final_chi2_red),
            "noise_known": self.baseline.problem.noise_known,
            "noise_model": self.baseline.noise_model or None,
            "method": "LM fits with independent windows and the baseline's weights; per model "
            "the wander or excess of its window residuals by restricted likelihood; per "
            "candidate four hypotheses (nothing, noise, effect, effect+noise) on one scale, "
            "F-test (or the likelihood ratio against a noise null) and BIC; confounding from "
            "the correlation of fitted signatures",
            "alpha": ALPHA,
        }


def rung(
    label: str, effect: str, fit: Fit, previous: Fit | None, n: int, noise: NoiseFit | None = None
) -> dict[str, Any]:
    """One step of the model ladder: chi2 ratio per invariant (RMS / noise floor), the change
    of BIC from the step before, and the noise its residuals hold (wander, excess)."""
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
        "chi2_red": finite_or_none(fit.rss / (n - fit.rank)) if n > fit.rank else None,
        "rms_over_floor": ratio,
        "delta_bic": None if step is None else finite_or_none(step),
        "heldout_chi2_red": finite_or_none(heldout_chi2_red(fit)) if n > fit.rank else None,
        "directions": fit.rank,
        "noise": describe(noise) if noise is not None else "",
    }


def conclude(d: Diagnosis, final: Fit, n: int, picked: Sequence[Candidate] = ()) -> None:
    """The verdict: what explains the misfit (an effect, a wander, an independent excess, or
    nothing), what was rejected and by how much (recal.diagnose.hypotheses), or that the model
    still fails (and where)."""
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
    noise0 = d.noise or NoiseFit(float("nan"))
    noise = d.final_noise or NoiseFit(final.rss)
    d.hypotheses = {"baseline": noise0.to_json_dict(), "final": noise.to_json_dict()}
    p_fit = float(stats.chi2.sf(final.rss, dof))
    # what the final model's residual holds beyond the windows' noise, if anything earns it
    rest = noise.kinds if noise.best_with_noise else set()
    d.model_fails = p_fit < ALPHA and rest != {"wander"}
    traded = [c.effect for c in d.candidates if c.effect in d.suggested_effects and c.warning]
    caveat = (
        f"; but {', '.join(traded)} trades off with the seed coefficients (see the warning): "
        "the residual may fall for the wrong reason"
        if traded
        else ""
    ) + (f"; {d.warning}" if d.warning else "")
    chi2 = f"chi2_red {d.chi2_red:.3g}" + (f" -> {d.final_chi2_red:.3g}" if added else "")
    if added:
        d.explanation = "effect"
        head = f"the misfit is {added} ({_evidence(picked[0])})" + _rejected(picked[0], noise0)
        if not d.model_fails:
            tail = (
                f"with it the residual is at the noise floor ({chi2})"
                if not rest
                else f"with it the rest is bias wander between the windows ({describe(noise)}; "
                f"{chi2})"
            )
            d.verdict = f"{head}; {tail}{caveat}"
            return
        d.verdict = head + "; " + _fails(d, final, p_fit, noise, f"with {added}")
        return
    best = next((c for c in d.candidates if c.identifiable and c.hypotheses), None)
    if not d.model_fails and not rest:
        d.explanation = "nothing"
        d.verdict = f"the model fits to the noise floor ({chi2}); no effect missing" + caveat
        return
    if rest == {"wander"}:
        d.explanation = "wander"
        d.verdict = (
            f"the misfit is bias wander between the windows ({describe(noise)}), not a missing "
            f"effect: {_effect_rejected(best)}; with the wander the model fits ({chi2})" + caveat
        )
        return
    d.explanation = "excess" if "excess" in rest else "unexplained"
    d.verdict = _fails(d, final, p_fit, noise, "with the seed model") + (
        f"; {_effect_rejected(best)}" if best is not None else ""
    )


def _evidence(c: Candidate) -> str:
    test = c.hypotheses.get("test")
    how = "likelihood ratio against the noise" if isinstance(test, dict) else "family-wise"
    return f"p {c.p_adjusted:.2g}, {how}"


def _rejected(c: Candidate, noise0: NoiseFit) -> str:
    """What the effect was preferred to, and by how much (IC: lower is better)."""
    h = c.hypotheses
    if not h:
        return ""
    best = h["effect+noise"] if h.get("best") == "effect+noise" else h["effect"]
    if h.get("noise") is not None and h.get("null") == "noise":
        kind = " and ".join(sorted(noise0.kinds)) or "noise"
        what = "bias wander" if kind == "wander" else f"{kind} ({describe(noise0)})"
        return (
            f"; {what} alone explains it worse (IC {h['noise']:.1f} against {best:.1f}, "
            f"delta {h['noise'] - best:+.1f})"
        )
    return f"; no wander explains it (IC with independent windows {h['nothing']:.1f} against {best:.1f})"


def _effect_rejected(c: Candidate | None) -> str:
    if c is None:
        return "no candidate effect could be fitted"
    return (
        f"the best candidate, {c.effect}, explains it worse (delta IC {c.delta_bic:+.1f})"
        if c.delta_bic >= 0
        else f"the best candidate, {c.effect}, explains it no better than chance "
        f"(p {c.p_adjusted:.2g})"
    )


def _fails(d: Diagnosis, final: Fit, p_fit: float, noise: NoiseFit, model: str) -> str:
    per = ", ".join(map(str, d.worst_positions))
    if d.worst_slews:
        per += "; worst slews " + ", ".join(
            f"{s['slew']} (rows {s['from_row']}->{s['to_row']})" for s in d.worst_slews
        )
    corr = ", ".join(f"{k} (r = {v:+.2f})" for k, v in list(d.residual_correlations.items())[:3])
    excess = [t for t in noise.admitted if t.kind == "excess"] if noise.best_with_noise else []
    why = (
        f"; the windows scatter more than their noise independently of one another "
        f"({describe(noise)}; no correlation at the {noise.tau_floor_s / 3600:.2g} h between "
        "windows: not a wander they can show, but model error, or a wander faster than the "
        "windows' spacing)"
        if excess
        else ""
    )
    return (
        f"the model still fails: chi2_red {d.final_chi2_red:.3g} {model} (p = {p_fit:.2g} "
        f"against the noise floor) and no candidate explains the rest{why}; worst positions "
        f"(0-based rows) {per}"
        + (f"; the residual correlates with {corr}" if corr else "")
        + "; an effect outside the catalogue may be missing: write it as a --plugin"
        + (f"; {d.warning}" if d.warning else "")
    )


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
