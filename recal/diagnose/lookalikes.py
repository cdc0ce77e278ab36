"""The look-alike check: does an effect outside the catalogue fit the misfit as well as the
suggested catalogue effect, and put the core coefficients elsewhere?

At one site the body-frame north direction of each window is a fixed linear function of the
measured Earth-rate and gravity directions (north = (w/Omega - sin(lat) up) / cos(lat)), so a
gyro bias that depends on heading, h_i north_i per axis (a magnetic, e.g. Faraday, sensitivity
of the coil), is exactly a change of the gyro scale factors plus a diagonal g-sensitivity.
`gyro.g_sensitivity` then takes a heading-dependent bias's whole misfit while the scale factors
move by h_i / (Omega cos(lat)): the residual falls for the wrong reason. The core-shift guard
(recal.diagnose.trust) measures that move in the baseline's 1-sigma, which the very misfit the
effect explains has widened (max(1, chi2_red): chi2_red 34 widens it 5.8 times), and missed it in
4 of 20 sessions of hours (benchmarks/bench_diagnose_hours.py, wrong reason, held-out seeds).

So diagnose fits the look-alike itself: the suggested model with the orientation-driven gyro
catalogue effect replaced by the heading-dependent bias (3 parameters). When the look-alike fits
as well (its extra misfit is what noise explains: the F-test of the suggested model over it is
not significant) and moves a core coefficient by more than CORE_SHIFT_SIGMA of the suggested
model's own 1-sigma from where the suggested model puts it, the two cannot be told apart here
and the diagnosis is NOT CONFIRMED, naming the look-alike and the move. A true g-sensitivity
with cross-axis terms is not a heading bias, and the look-alike then does not fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from recal.diagnose.candidates import ALPHA, Candidate
from recal.diagnose.diagnosis import Diagnosis
from recal.diagnose.fit import Fit, best_fit
from recal.diagnose.shift import CORE_SHIFT_SIGMA, SHIFT_CHECKS, core_shift
from recal.errors import RecalInputError
from recal.model.plugins import values_by_term
from recal.model.terms import Context, Term, catalogue_terms
from recal.solve.options import CalibrationOptions
from recal.solve.result import CalibrationResult


@dataclass(frozen=True)
class HeadingBias(Term):
    """b_g,i += h_i north_i: a gyro bias proportional to the north direction along each axis."""

    def offset(self, p: np.ndarray, ctx: Context) -> np.ndarray:
        return p[:, None, :] * np.asarray(ctx["north"])[None]


HEADING_BIAS = HeadingBias(
    "gyro.heading_bias",
    "gyro",
    ("hx", "hy", "hz"),
    "deg/h",
    (0.01, 0.01, 0.01),
    (0.0, 0.0, 0.0),
    "Bias proportional to the north direction along the axis (a heading-dependent, e.g. "
    "magnetic, bias): out of the catalogue, fitted only as a look-alike.",
    needs=frozenset({"north"}),
)


def _orientation_driven(name: str) -> bool:
    """A gyro catalogue effect driven by the orientation (specific force), not by temperature
    or time: the kind a heading-dependent bias looks like."""
    term = catalogue_terms().get(name)
    return term is not None and term.sensor == "gyro" and "specific_force_g" in term.needs


def lookalike_check(
    d: Diagnosis,
    base: CalibrationResult,
    opt: CalibrationOptions,
    chosen: Sequence[str],
    final: Fit,
    picked: Sequence[Candidate],
) -> None:
    """The module's check on the diagnosis ``d`` whose suggested model is ``final``; sets
    ``d.trustworthy``, ``d.warning`` and ``d.lookalike`` when the look-alike fits as well and
    puts the core elsewhere."""
    swapped = [c.effect for c in picked if _orientation_driven(c.effect)]
    if not swapped or final.sd is None or not np.isfinite(final.rss):
        return
    effects = [e for e in (*chosen, *d.suggested_effects) if e not in swapped]
    alt_opt = replace(opt, plugin_terms=[*opt.plugin_terms, HEADING_BIAS])
    try:
        alt = best_fit(base, alt_opt, [*effects, HEADING_BIAS.name],
                       values_by_term(final.problem.layout, final.theta))  # fmt: skip
    except RecalInputError:
        return
    n = final.problem.n_residuals
    if not np.isfinite(alt.rss) or alt.degenerate or n <= final.rank:
        return
    dof = n - final.rank
    extra = max(alt.rss - final.rss, 0.0)
    k = max(final.rank - alt.rank, 1)
    p = float(stats.f.sf(extra / k / max(final.rss / dof, 1e-300), k, dof))
    sd = np.where(np.isfinite(final.sd), final.sd, np.nan)
    shifts = core_shift(final.problem.layout.names, final.theta, sd,
                         alt.problem.layout.names, alt.theta)  # fmt: skip
    top = next(iter(shifts), None)
    d.lookalike = {
        "effect": HEADING_BIAS.name,
        "replaces": swapped,
        "chi2": float(alt.rss),
        "chi2_suggested": float(final.rss),
        "p_suggested_better": p,
        "core_shift": shifts,
    }
    if p < ALPHA or top is None or abs(shifts[top]) <= CORE_SHIFT_SIGMA:
        return
    d.trustworthy = False
    moved = ", ".join(f"{k} {abs(v):.1f}" for k, v in shifts.items() if abs(v) > 1)
    sentence = (
        f"NOT CONFIRMED: a heading-dependent gyro bias (out of the catalogue) fits these "
        f"positions as well as {', '.join(swapped)} (chi2 {alt.rss:.1f} against "
        f"{final.rss:.1f}, p {p:.2g}) and puts the core coefficients elsewhere ({moved} sigma "
        f"of the suggested model's own): these data cannot tell them apart; check: {SHIFT_CHECKS}"
    )
    d.warning = f"{d.warning}; {sentence}" if d.warning else sentence
