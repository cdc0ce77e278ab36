"""A starting point from the data alone, used only where the design supports it.

Without a prior file the fit starts from, and holds what it cannot see at, a prior derived from
the windows: per triad an axis-aligned ellipsoid fitted to the outputs gives each axis's scale
factor and bias, misalignment and every other term start neutral. On a design that does not
span the sphere -- a hull-fixed unit whose gravity stays near one axis, a single heading -- that
fit is as good as its noise: it gave a vessel's accelerometer scale factors of 1e-5 and a
vertical bias of 141,262 g. The fit is therefore judged against the window noise:
:func:`ellipsoid_fit` propagates each window's standard error through the fit to the 1-sigma of
every scale factor and bias, and :func:`data_prior` uses the fit only when all of them are
within :data:`SUPPORT` times the 1-sigma a data-derived prior is documented to carry (the
sensor class default, :data:`recal.solve.consider.DEFAULT_PRIOR_SIGMA`). A coefficient held at
that start carries the larger of the class default and the fit's own 1-sigma, so it is known to
its stated uncertainty. Otherwise the triad starts from the nominal: one common scale factor from
the median output norm, biases zero, with what that may be off by for a unit of unknown history
(:data:`NOMINAL_BIAS_SIGMA`). On a hull-fixed design the fit's
1-sigma is hundreds to thousands of times the class default (vertical scale factors to 200-900 %,
biases to tens of g or deg/h: refused); on 12 random orientations of a FOG with 8 s windows it is
1.4 times it (used: a swarm searches a few sigma about its start and needs that start).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from recal.model.error_model import ParameterLayout
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H, normal_gravity_g
from recal.solve.consider import DEFAULT_PRIOR_SIGMA, sensor_class

#: 1-sigma of the nominal start's biases (zero) for a unit of unknown history, per sensor class,
#: in input units (deg/h, g): how far from zero a bias may sit, not how far it moves between two
#: calibrations (recal.solve.consider.DEFAULT_PRIOR_SIGMA). A navigation FOG's turn-on bias is up
#: to about 0.5 deg/h (a KVH 1750; ``service.capture_sim.kvh_like_truth``), the same figure the
#: rest check assumes for a unit without a prior (recal.detect.rest); a navigation
#: accelerometer's 1 mg and the MEMS figures are the class defaults. The median norm's common
#: scale factor then errs by about bias / reference as well: its 1-sigma is the class's scale
#: default and that, added in quadrature (where the bias is below the reference).
NOMINAL_BIAS_SIGMA: dict[str, dict[str, float]] = {
    "navigation": {"gyro": 0.5, "accel": 1e-3},
    "mems": {"gyro": DEFAULT_PRIOR_SIGMA["mems"]["gyro.bias"], "accel": 3e-2},
}
#: Parameters of the axis-aligned ellipsoid a x^2 + b y^2 + c z^2 + d x + e y + f z = 1.
ELLIPSOID_PARAMETERS = 6
#: The ellipsoid start is used when the window noise pins its every scale factor and bias to
#: within this many times the sensor class's default prior 1-sigma (an order of magnitude: what
#: the designs it must refuse miss by is two to four orders).
SUPPORT = 10.0


class EllipsoidFit(NamedTuple):
    """Per-axis scale (output units per input unit) and bias (input units) of a triad, each with
    its 1-sigma from the window noise (the scale's relative)."""

    scale: np.ndarray
    bias: np.ndarray
    scale_sd_rel: np.ndarray
    bias_sd: np.ndarray


def _scale_bias(coef: np.ndarray, span: np.ndarray, centre: np.ndarray, reference: float):
    """(scale, bias) per axis of the ellipsoid ``coef`` in conditioned coordinates, or None when
    it is not an ellipsoid (a semi-axis not real)."""
    a, d = coef[:3], coef[3:]
    if np.any(a <= 0):
        return None
    c = -d / (2 * a)
    g = 1 + np.sum(a * c * c)
    if g <= 0:
        return None
    scale = np.sqrt(g / a) * span / reference  # semi-axes in output units over the reference
    return scale, (centre + c * span) / scale


def ellipsoid_fit(
    output: np.ndarray, reference: float, noise: np.ndarray | None = None
) -> EllipsoidFit | None:
    """Axis-aligned ellipsoid fitted to the outputs (M, 3), with the 1-sigma of what it gives.

    ``noise`` (M, 3): each window mean's standard error in output units; each equation's noise
    is the gradient of the ellipsoid equation times it, and the covariance is that of the
    least-squares estimate under it: how well the design pins the fit down on this noise (a
    misfit -- misalignment, an effect the ellipsoid lacks -- is the solver's business, not the
    design's). Without noise the residual RMS of the fit is the equation noise. None when the fit is not
    defined: no more windows than its 6 parameters (nothing would check it), an axis that does
    not vary at all, a singular design or a fit that is not an ellipsoid.
    """
    M = len(output)
    if M <= ELLIPSOID_PARAMETERS:
        return None
    span = np.ptp(output, axis=0)
    if not np.all(span > 0):
        return None
    centre = output.mean(axis=0)
    u = (output - centre) / span  # conditioned coordinates
    G = np.column_stack([u**2, u])
    _, s, Vt = np.linalg.svd(G, full_matrices=False)
    if not s[-1] > 1e-12 * s[0]:
        return None
    inv = (Vt.T / s**2) @ Vt  # (G^T G)^-1
    coef = inv @ (G.T @ np.ones(M))  # least squares
    r = G @ coef - 1.0
    if noise is None:
        cov = inv * float(r @ r) / (M - ELLIPSOID_PARAMETERS)
    else:
        # each equation's noise: its gradient in the outputs times their standard errors; the
        # covariance of the least-squares estimate under it (sandwich), widened by any misfit
        a, d = coef[:3], coef[3:]
        var = np.sum(((2 * a * u + d) / span * noise) ** 2, axis=1)
        if not np.all(np.isfinite(var) & (var > 0)):
            return None
        cov = inv @ ((G.T * var) @ G) @ inv
    values = _scale_bias(coef, span, centre, reference)
    if values is None:
        return None
    scale, bias = values
    # first-order propagation to scale and bias: central differences in the 6 coefficients
    step = 1e-6 * np.maximum(np.abs(coef), np.sqrt(np.diag(cov)))
    jac = np.zeros((6, ELLIPSOID_PARAMETERS))
    for j in range(ELLIPSOID_PARAMETERS):
        hi, lo = coef.copy(), coef.copy()
        hi[j] += step[j]
        lo[j] -= step[j]
        a, b = _scale_bias(hi, span, centre, reference), _scale_bias(lo, span, centre, reference)
        if a is None or b is None:
            return None  # at the edge of being an ellipsoid: not a usable start
        jac[:, j] = (np.concatenate(a) - np.concatenate(b)) / (2 * step[j])
    sd = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", jac, cov, jac), 0, None))
    return EllipsoidFit(scale, bias, sd[:3] / np.abs(scale), sd[3:])


def references(lat: float, h: float) -> dict[str, float]:
    """What each triad reads at rest in input units: Earth rate (deg/h) and gravity (g)."""
    return {"gyro": OMEGA_IE_DEG_H, "accel": normal_gravity_g(lat, h)}


def common_start(positions: Positions, layout: ParameterLayout, lat: float, h: float):
    """The nominal start: per triad one scale factor from the median output norm, biases and
    every other term neutral."""
    theta = layout.neutral()
    slices = layout.term_slices()
    for m, ref in ((m, references(lat, h)[m.sensor]) for m in layout.models):
        out = positions.gyro if m.sensor == "gyro" else positions.accel
        theta[slices[f"{m.sensor}.scale"]] = np.median(np.linalg.norm(out, axis=1)) / ref
    return theta


class DataPrior(NamedTuple):
    theta: np.ndarray  # (D,)
    how: dict[str, str]  # sensor -> how its scale and bias were derived, in plain words
    sensor_class: str  # the class whose default 1-sigma the start is judged against
    #: (D,) the start's own 1-sigma for the scale factors and biases (the ellipsoid fit's, or
    #: what the nominal start may be off by, NOMINAL_BIAS_SIGMA), NaN for the other terms
    sigma: np.ndarray


def data_prior(
    positions: Positions,
    layout: ParameterLayout,
    lat: float,
    h: float,
    earth_rate_contrast: float,
) -> DataPrior:
    """A prior from the data alone (module docstring): the ellipsoid fit per triad where the
    window noise pins its every scale factor and bias within :data:`SUPPORT` times the sensor
    class's default 1-sigma, else the nominal :func:`common_start`. ``earth_rate_contrast``: the gyro contrast that makes
    a unit "navigation" class (:func:`recal.solve.consider.sensor_class`)."""
    theta = common_start(positions, layout, lat, h)
    cls = sensor_class(positions, layout, theta, earth_rate_contrast)
    limits = DEFAULT_PRIOR_SIGMA[cls]
    slices = layout.term_slices()
    how = {}
    sigma = np.full(layout.size, np.nan)
    for m in layout.models:
        s = m.sensor
        ref = references(lat, h)[s]
        out = positions.gyro if s == "gyro" else positions.accel
        fit = ellipsoid_fit(out, ref, positions.std_of_mean(s))
        nominal = "common scale from the median norm, bias zero"
        # what the nominal start may be off by (it is what is held where nothing is seen)
        b_sd = NOMINAL_BIAS_SIGMA[cls][s]
        k = slices[f"{s}.scale"]
        # (a bias that may exceed the reference makes the norm no scale measure at all: the
        # class default stands -- a gyro classed MEMS only for want of noise columns)
        rel = np.hypot(limits["scale"], b_sd / ref) if b_sd < ref else limits["scale"]
        sigma[k] = rel * np.abs(theta[k])
        sigma[slices[f"{s}.bias"]] = b_sd
        if fit is None:
            how[s] = f"{nominal} (no ellipsoid fit: too few or too alike positions)"
            continue
        worst_scale, worst_bias = float(fit.scale_sd_rel.max()), float(fit.bias_sd.max())
        if worst_scale > SUPPORT * limits["scale"] or worst_bias > SUPPORT * limits[f"{s}.bias"]:
            axis = "xyz"[int(np.argmax(fit.scale_sd_rel / limits["scale"]))]
            unit = "deg/h" if s == "gyro" else "g"
            how[s] = (
                f"{nominal} (the ellipsoid fit is not supported by these positions: on their "
                f"noise it pins the scale factors only to {worst_scale:.2g} relative (worst "
                f"axis {axis}) and the biases to {worst_bias:.2g} {unit}: more than {SUPPORT:g}x "
                f"the {limits['scale']:.2g} and {limits[f'{s}.bias']:.2g} {unit} a data-derived "
                f"prior carries, {cls} class)"
            )
            continue
        theta[slices[f"{s}.scale"]] = fit.scale
        theta[slices[f"{s}.bias"]] = fit.bias
        sigma[slices[f"{s}.scale"]] = fit.scale_sd_rel * np.abs(fit.scale)
        sigma[slices[f"{s}.bias"]] = fit.bias_sd
        how[s] = "scale and bias from an ellipsoid fit"
    return DataPrior(theta, how, cls, sigma)
