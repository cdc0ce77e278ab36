"""How far adding an effect moves the seed coefficients (scale, bias, misalignment) in their
1-sigma (:func:`core_shift`), how much of a coefficient's uncertainty the effect explains
(:func:`multiple_correlation`), and what to say when the move is large: what would separate them
(:func:`core_advice`), what else could fit as well (:func:`look_alikes`), how to check
(:func:`shift_check`). The rules are in the module doc of :mod:`recal.diagnose.effects`; the
candidates (:mod:`recal.diagnose.candidates`) and the diagnosis's trust
(:mod:`recal.diagnose.trust`) both use them."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Shift of a seed coefficient, in its current 1-sigma, and correlation with the effect above
#: which the candidate carries a trade-off warning.
SHIFT_WARN_SIGMA = 5.0
#: Shift of a seed coefficient, in its current 1-sigma, beyond which the fit of an effect is not
#: trusted without a check (``trustworthy``: false), whatever the correlation.
CORE_SHIFT_SIGMA = 3.0
CORRELATION_WARN = 0.9


def core_indices(names: list[str]) -> list[int]:
    core = (".scale.", ".bias.", ".misalignment.")
    return [i for i, nm in enumerate(names) if nm.split(".", 1)[0] in ("gyro", "accel")
            and any(c in nm for c in core) and nm.count(".") == 2]  # fmt: skip


def core_shift(
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
    for i in core_indices(list(names0)):
        j = where.get(names0[i])
        if j is None or not sd0[i] > 0:
            continue
        shifts[names0[i]] = float((theta1[j] - theta0[i]) / sd0[i])
    top = sorted(shifts, key=lambda k: -abs(shifts[k]))[:most]
    return {k: shifts[k] for k in top}


def multiple_correlation(cov: np.ndarray, j: int, eff: np.ndarray) -> float:
    """Multiple correlation of parameter ``j`` with the parameters ``eff`` (how much of j's
    uncertainty the effect explains): sqrt(c_je C_ee^-1 c_ej / c_jj), in [0, 1]."""
    c_je = cov[j, eff]
    C_ee = cov[np.ix_(eff, eff)]
    if cov[j, j] <= 0:
        return 0.0
    r2 = float(c_je @ np.linalg.pinv(C_ee, rcond=1e-12) @ c_je / cov[j, j])
    return float(np.sqrt(np.clip(r2, 0.0, 1.0)))


def core_advice(needs: frozenset[str], effect: str) -> str:
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


def look_alikes(needs: frozenset[str]) -> str:
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


def shift_check(effect: str, needs: frozenset[str], coefficient: str, shift: float) -> str:
    """Why a fit that moves ``coefficient`` by ``shift`` sigma needs a check, and which."""
    return (
        f"adding {effect} moves {coefficient} by {abs(shift):.1f} sigma (more than "
        f"{CORE_SHIFT_SIGMA:g}): the fall of chi2 does not show {effect} is right, since "
        f"{look_alikes(needs)} would fit as well and move the coefficients elsewhere; before "
        f"using them: {SHIFT_CHECKS}"
    )
