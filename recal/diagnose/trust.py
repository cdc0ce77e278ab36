"""Whether the fit of an effect is to be trusted: how far adding it moves the seed coefficients
(scale, bias, misalignment) in their 1-sigma (:func:`_core_shift`), whether it trades off with
them (:func:`_trade_off`), the diagnosis's trust in its suggested effects together
(:func:`_trust`) and the same check for a calibration with effects (:func:`effects_check`).
The rules are in the module doc of :mod:`recal.diagnose.effects`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from recal.diagnose.fit import Fit, _finite
from recal.solve.calibrate import CalibrationOptions, CalibrationResult, calibrate

if TYPE_CHECKING:  # annotations only: those modules import this one
    from recal.diagnose.candidates import Candidate
    from recal.diagnose.diagnosis import Diagnosis


#: Shift of a seed coefficient, in its current 1-sigma, and correlation with the effect above
#: which the candidate carries a trade-off warning.
SHIFT_WARN_SIGMA = 5.0
#: Shift of a seed coefficient, in its current 1-sigma, beyond which the fit of an effect is not
#: trusted without a check (``trustworthy``: false), whatever the correlation.
CORE_SHIFT_SIGMA = 3.0
CORRELATION_WARN = 0.9


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
