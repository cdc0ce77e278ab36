"""Whether the suggested effects are to be trusted together: how far they move the seed
coefficients from the baseline (:func:`trust_diagnosis`, with :mod:`recal.diagnose.shift`), and the same
check for a calibration with effects (:func:`effects_check`). The rules are in the module doc of
:mod:`recal.diagnose.effects`; each candidate's own trade-off is in
:mod:`recal.diagnose.candidates`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from recal.diagnose.candidates import Candidate
from recal.diagnose.diagnosis import Diagnosis
from recal.diagnose.fit import Fit, finite_or_none
from recal.diagnose.shift import CORE_SHIFT_SIGMA, SHIFT_CHECKS, core_shift, look_alikes
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from recal.solve.result import CalibrationResult


def trust_diagnosis(d: Diagnosis, fit0: Fit, final: Fit, picked: Sequence[Candidate]) -> None:
    """The diagnosis's trust: how far the suggested effects together move the seed coefficients
    from the baseline (in its 1-sigma), and the warning when any moves by more than
    CORE_SHIFT_SIGMA."""
    if not picked or fit0.sd is None:
        return
    shifts = core_shift(fit0.problem.layout.names, fit0.theta,
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
        f"until checked: {look_alikes(needs)} would fit as well and move them elsewhere; "
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
    shifts = core_shift(seed.layout.names, seed.theta, sd0, result.layout.names, result.theta)
    top = list(shifts)
    trustworthy = not top or abs(shifts[top[0]]) <= CORE_SHIFT_SIGMA
    needs = frozenset().union(*(result.terms[e].needs for e in effects))
    warning = "" if trustworthy else (
        f"NOT CONFIRMED: {', '.join(effects)} moves the core coefficients by more than "
        f"{CORE_SHIFT_SIGMA:g} sigma from the seed model's fit ("
        + ", ".join(f"{k} {abs(shifts[k]):.1f}" for k in top if abs(shifts[k]) > 1)
        + f" sigma): not better than the seed model's coefficients until checked; "
        f"{look_alikes(needs)} would fit as well; check: {SHIFT_CHECKS}"
    )  # fmt: skip
    return {"effects": effects, "trustworthy": trustworthy,
            "core_shift": shifts, "seed_chi2_red": finite_or_none(seed.chi2_red),
            "warning": warning}  # fmt: skip
