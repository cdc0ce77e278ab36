"""Whether a calibration result can be believed: an absurd one is an error, never an output.

A fit can land somewhere no unit can be: on near-coplanar gravity a data-derived start once gave
accelerometer scale factors of 1e-5 and a vertical bias of 141,262 g at a 1-sigma of 0.001 g,
and ``-o`` wrote it. The engine now refuses a data-derived start the design cannot support
(:mod:`recal.solve.start`) and holds what it cannot see exactly at the prior, so such a result
should not arise; :func:`unbelievable` is the last check, on every scale factor and bias, before
anything is reported or written:

* the value is finite;
* an estimated scale factor keeps its start's sign and stays within :data:`MAX_SCALE_FACTOR` of
  it (a calibration corrects a scale factor by parts per thousand, a MEMS's by a few per cent);
* a bias stays within the reference magnitude its triad measures at rest (gravity, or Earth
  rate for a gyro that sees it; three times a MEMS's documented turn-on bias for a gyro blind
  to it) or within twice its start, whichever is larger: a unit in raw counts with an ADC
  offset has a bias of several g, which its prior or the ellipsoid fit shows;
* an estimated one's reported 1-sigma says something: a scale factor's below
  :data:`MAX_RELATIVE_SIGMA` of it, a bias's within that bound. A held one is never judged
  here: a prior wider than that bound is held at the bound (:func:`physical_bounds`), so a
  coefficient the positions cannot show never refuses the part they do show (issue 36);
* an estimated one's 1-sigma from the window noise is not below :data:`MIN_SIGMA_SHARE` of the
  least that noise allows at the start: 1 / |J_i|, the whitened Jacobian column of that
  coefficient alone (every other one known). A fit that ran to where the model amplifies the
  noise reports a sigma the data cannot give.
"""

from __future__ import annotations

import numpy as np

from recal.solve.consider import DEFAULT_PRIOR_SIGMA
from recal.solve.observability import jacobian
from recal.solve.problem import Problem

#: A scale factor that changed by more than this factor from its start is not believable.
MAX_SCALE_FACTOR = 2.0
#: A measurement 1-sigma below this share of the window noise's bound at the start is not
#: believable (the bound is exact for a linear problem; the share allows for the change of the
#: Jacobian between the start and a sound solution).
MIN_SIGMA_SHARE = 0.5
#: A scale factor whose reported 1-sigma is above this share of it says nothing.
MAX_RELATIVE_SIGMA = 0.5
#: The terms checked: the seed model's scale factors and biases.
CHECKED = ("gyro.scale", "gyro.bias", "accel.scale", "accel.bias")


def physical_bounds(
    layout, theta0: np.ndarray, references: dict[str, float], blind_gyro: bool = False
) -> np.ndarray:
    """(D,) the largest 1-sigma a coefficient may carry and still say something, inf where no
    bound applies: a scale factor's :data:`MAX_RELATIVE_SIGMA` of its start, a bias's the
    magnitude its triad reads at rest (gravity, Earth rate; three times a MEMS's turn-on bias
    for a gyro blind to Earth rate) or twice its start, whichever is larger.

    A held coefficient whose prior is wider than this is held at the bound (issue 36): no unit
    can be further off, so the bound is the honest 1-sigma, and a prior without knowledge (a
    default 1-sigma of 1.8e3 deg/h on an unseen gyro bias) no longer makes the whole answer
    unbelievable. The estimated part stands; it is :func:`unbelievable` that judges it."""
    out = np.full(layout.size, np.inf)
    for term, sl in layout.term_slices().items():
        if term not in CHECKED:
            continue
        v0 = np.asarray(theta0[sl], float)
        if term.endswith(".scale"):
            out[sl] = MAX_RELATIVE_SIGMA * np.abs(v0)
            continue
        sensor = term.split(".", 1)[0]
        ref = references[sensor]
        if sensor == "gyro" and blind_gyro:
            ref = 3.0 * DEFAULT_PRIOR_SIGMA["mems"]["gyro.bias"]
        out[sl] = np.maximum(ref, 2.0 * np.abs(v0))
    return out


def unbelievable(
    problem: Problem,
    theta: np.ndarray,
    theta0: np.ndarray,
    typical: np.ndarray,
    estimated: np.ndarray,
    sd: np.ndarray,
    sd_measurement: np.ndarray,
    references: dict[str, float],
    blind_gyro: bool = False,
) -> str | None:
    """Why the result ``theta`` (D,) cannot be believed, naming the coefficient, or None.

    ``theta0``: the start (the prior); ``estimated`` (D,) bool; ``sd`` (D,): the reported
    1-sigma; ``sd_measurement`` (D,): the window noise's part of it (NaN when unknown: not
    checked); ``references``: sensor -> what it reads at rest in input units; ``blind_gyro``:
    the gyro cannot see Earth rate."""
    layout = problem.layout
    names = layout.names
    slices = layout.term_slices()
    idx = [i for t in CHECKED if t in slices for i in range(layout.size)[slices[t]]]
    if not np.all(np.isfinite(theta)):
        return f"{names[int(np.flatnonzero(~np.isfinite(theta))[0])]} is not finite"
    bounds = physical_bounds(layout, theta0, references, blind_gyro)
    for i in idx:
        term = names[i].rsplit(".", 1)[0]
        v, v0, s = float(theta[i]), float(theta0[i]), float(sd[i])
        if term.endswith(".scale"):
            ratio = v / v0 if v0 != 0 else np.inf
            if estimated[i] and not 1 / MAX_SCALE_FACTOR <= ratio <= MAX_SCALE_FACTOR:
                return (
                    f"{names[i]} = {v:.6g} against its start {v0:.6g} (a factor {ratio:.3g}; a "
                    f"believable scale factor keeps its sign and stays within {MAX_SCALE_FACTOR:g}x)"
                )
            if estimated[i] and s > MAX_RELATIVE_SIGMA * abs(v):
                return (
                    f"{names[i]} = {v:.6g} with a 1-sigma of {100 * s / abs(v):.3g} % (estimated)"
                )
            continue
        bound = float(bounds[i])
        if abs(v) > bound:
            return (
                f"{names[i]} = {v:.6g} is beyond {bound:.4g}, the magnitude its triad measures "
                f"at rest (or twice its start {v0:.4g})"
            )
        if estimated[i] and s > bound:
            return (
                f"{names[i]} = {v:.6g} with a 1-sigma of {s:.3g}, more than the {bound:.4g} it "
                "may be at all"
            )
    idx = [i for i in idx if estimated[i]]
    checked = [i for i in idx if np.isfinite(sd_measurement[i])]
    if not checked:
        return None
    # the least 1-sigma the window noise allows each coefficient at the start, alone
    J = jacobian(problem, theta0, np.diag(typical)[checked])  # (R, k)
    floor = typical[checked] / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    for i, f in zip(checked, floor, strict=True):
        if sd_measurement[i] < MIN_SIGMA_SHARE * f:
            return (
                f"{names[i]} = {theta[i]:.6g} with a 1-sigma of {sd_measurement[i]:.3g}, below "
                f"the {f:.3g} the window noise allows it at the start: the fit ran to where the "
                "model amplifies the noise"
            )
    return None
