"""The candidate effects of diagnose, each scored on top of the current model
(:func:`score_candidates`: delta BIC, the nominal F-test, the share of the misfit explained), their
family-wise p-values from a parametric bootstrap with the residuals' real noise correlation
(:func:`family_pvalues`), and which candidates share a signature (:func:`mark_confounding`). The
rules are in the module doc of :mod:`recal.diagnose.effects`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from recal.diagnose.fit import FIT_INFO_MIN, Fit, fit_effects, heldout_chi2_red
from recal.diagnose.hypotheses import NOISE, NoiseFit, noise_fit
from recal.diagnose.noise_test import (
    NOISE_NULL_DRAWS,
    NOISE_NULL_MAX_RESIDUALS,
    noise_null_test,
)
from recal.diagnose.shift import (
    CORE_SHIFT_SIGMA,
    CORRELATION_WARN,
    SHIFT_WARN_SIGMA,
    core_advice,
    core_shift,
    multiple_correlation,
    shift_check,
)
from recal.errors import RecalInputError
from recal.model.plugins import values_by_term
from recal.model.positions import Positions
from recal.model.terms import Term, catalogue_terms
from recal.solve.observability import jacobian
from recal.solve.options import CalibrationOptions
from recal.solve.problem import Problem
from recal.solve.result import CalibrationResult

ALPHA = 0.01
#: Share of the excess misfit by which another candidate must explain more to be named as the
#: one that explains it better.
BETTER = 0.1


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
    #: the model with the effect, its misfit as noise (recal.diagnose.hypotheses)
    noise: NoiseFit | None = None
    #: the four hypotheses' figures (IC, recal.diagnose.hypotheses) and which explains best:
    #: {"nothing", "noise", "effect", "effect+noise", "best", "null", "test"}
    hypotheses: dict[str, Any] = field(default_factory=dict)

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
            "hypotheses": self.hypotheses,
        }


def default_candidates(positions: Positions, sensors: Sequence[str], t0_c: float) -> list[Term]:
    """Catalogue effects for the triads present (needs are checked when fitting)."""
    return [t for t in catalogue_terms(t0_c).values() if t.sensor in sensors]


#: Signature correlation above which two candidates are listed as confounded / the same.
CONFOUNDED = 0.7
SAME = 0.9


def score_candidates(
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
        fit = fit_effects(base, opt, effects + [term.name], start=values_by_term(
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
    cand.noise = noise_fit(fit)
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


def family_pvalues(current: Fit, scored: list[Candidate], n: int, rng: np.random.Generator) -> None:
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


def against_noise(
    noise: NoiseFit, scored: list[Candidate], n: int, rng: np.random.Generator
) -> None:
    """Each candidate judged against the best explanation without it (recal.diagnose.hypotheses):
    the current model with independent windows, or with the noise (wander, excess) its
    residuals hold. ``delta_bic`` becomes the candidate's best figure (with or without noise)
    minus that best, plus its directions' price (with no noise admitted anywhere: the plain
    delta BIC). Where the best null holds noise, the F-test's premise (independent windows)
    fails, so the test is the profile likelihood ratio of effect plus noise over noise,
    the noise re-fitted on both sides, family-wise by a parametric bootstrap of that null
    (recal.diagnose.noise_test); otherwise the F-test's family-wise p stands.
    ``significant``: that p below ALPHA and ``delta_bic`` below 0."""
    ok = [c for c in scored if c.identifiable and c.noise is not None]
    null_ic = noise.best_ic
    null = NOISE if noise.best_with_noise else "nothing"
    for c in ok:
        assert c.noise is not None
        price = c.added_directions * np.log(n)
        effect, both = c.noise.ic(False) + price, c.noise.ic(True) + price
        with_noise = c.noise.best_with_noise
        c.delta_bic = (both if with_noise else effect) - null_ic
        c.hypotheses = {
            "nothing": round(float(noise.ic(False)), 3),
            "noise": round(float(noise.ic(True)), 3) if noise.admitted else None,
            "effect": round(float(effect), 3),
            "effect+noise": round(float(both), 3) if c.noise.admitted else None,
            "best": ("effect+noise" if with_noise else "effect") if c.delta_bic < 0 else null,
            "null": null,
            "noise_null": noise.to_json_dict(),
            "noise_with_effect": c.noise.to_json_dict(),
        }
        c.hypotheses["test"] = "F, family-wise by parametric bootstrap"
    w = noise.inputs  # the current fit's, as its noise was estimated from them
    tested = [c for c in ok if c.jac is not None]
    if null == NOISE and w is not None and tested and len(w.r_std) > NOISE_NULL_MAX_RESIDUALS:
        # the bootstrap is dense; past its size the likelihood ratio of the linear-time noise
        # fits is taken against chi-square, Bonferroni over the candidates, and says so
        for c in tested:
            assert c.noise is not None
            lr = (noise.chi2 - noise.gain_all) - (c.noise.chi2 - c.noise.gain_all)
            c.p_value = float(stats.chi2.sf(max(lr, 0.0), c.added_directions))
            c.p_adjusted = min(1.0, c.p_value * len(tested))
            c.hypotheses["test"] = {
                "likelihood_ratio": round(float(lr), 3),
                "dof": c.added_directions,
                "null": f"chi-square x {len(tested)} candidates (Bonferroni): the bootstrap "
                f"runs up to {NOISE_NULL_MAX_RESIDUALS} window residuals, these are "
                f"{len(w.r_std)}",
            }
    elif null == NOISE and w is not None and tested:
        test = noise_null_test(
            w.r_std, w.sigma, w.sensitivity, w.t, w.sessions, w.taus, w.jacobian,
            [(c.effect.split(".", 1)[0], c.jac, c.added_directions, w.r_std - c.signature)
             for c in tested],
            noise.model(), rng,
        )  # fmt: skip
        for c, lr, p, pf in zip(tested, test.lr, test.p_nominal, test.p_family, strict=True):
            c.p_value, c.p_adjusted = float(p), float(pf)
            c.hypotheses["test"] = {
                "likelihood_ratio": round(float(lr), 3),
                "dof": c.added_directions,
                "null": "the noise's own draws (parametric bootstrap, family-wise)",
                "draws": NOISE_NULL_DRAWS,
            }
    for c in ok:
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


def mark_confounding(ranked: list[Candidate]) -> None:
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


def _trade_off(cand: Candidate, current: Fit, fit: Fit, sl: slice) -> None:
    """How far the effect moves the seed coefficients (in their current 1-sigma) and whether
    it trades off with them in the extended model (module doc)."""
    if current.sd is None or fit.cov is None:
        return
    names1 = fit.problem.layout.names
    shifts = core_shift(current.problem.layout.names, current.theta,
                         np.where(np.isfinite(current.sd), current.sd, np.nan), names1, fit.theta)  # fmt: skip
    if not shifts:
        return
    cand.core_shift = shifts
    cov = fit.cov
    eff = np.arange(cov.shape[0])[sl]
    name = next(iter(shifts))
    j = names1.index(name)
    corr = multiple_correlation(cov, j, eff)
    cand.trade_off = {"coefficient": name, "shift_sigma": shifts[name], "correlation": corr}
    if abs(shifts[name]) > CORE_SHIFT_SIGMA:
        cand.trustworthy = False
        cand.check = shift_check(cand.effect, cand.needs, name, shifts[name])
    if abs(shifts[name]) >= SHIFT_WARN_SIGMA and abs(corr) >= CORRELATION_WARN:
        cand.advice = core_advice(cand.needs, cand.effect)
        cand.warning = (
            f"adding {cand.effect} moves {name} by {abs(shifts[name]):.1f} sigma: they trade off "
            f"in these positions (multiple correlation {corr:.2f}), so the fit is only as right as the "
            f"effect's model; to separate them: {cand.advice}"
        )
