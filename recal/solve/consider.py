"""Consider covariance: what the coefficients held at the prior add to every reported 1-sigma.

A fit estimates the observable directions and holds the rest at the prior. The held values are
not exact: a previous calibration has its own uncertainty, and a prior derived from the data
assumes, for example, zero misalignment where a MEMS triad has about 1 %. Their error moves the
estimated coefficients (six accelerometer faces: a 1e-2 rad misalignment held at zero moves the
scale factors by about E^2 / 2 = 50-300 ppm), and the Gauss-Newton covariance of the estimated
directions alone does not show it.

The held part's prior covariance ``Sigma_u`` (in the held directions) is propagated by sigma
points, because the held directions often enter the invariants only at second order (a
misalignment on a face), where a linear propagation gives exactly zero:

    for each sigma point du = +-sqrt(lambda_i) v_i of Sigma_u:
        dz = -pinv(J_z) (r(theta + T_h du) - r(theta))      (one Gauss-Newton step)
        e  = T dz + T_h du                                  (error if the held part were off by du)
    C_consider = 1/2 sum over points e e^T

For a linear problem this is exactly (T S - T_h) Sigma_u (T S - T_h)^T with S = -pinv(J_z) J_u;
at second order it is the mean square error the held part causes. The total covariance is the
measurement part plus this one (the held part is independent of the window noise).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from recal.model.error_model import ParameterLayout
from recal.solve.observability import jacobian
from recal.solve.problem import Problem

#: 1-sigma of a coefficient held at a prior that carries no uncertainty of its own, per sensor
#: class, in the coefficient's own unit ("rel" for scale factors: a fraction of the value).
#: "navigation": a navigation-grade triad (FOG/RLG gyro, whose Earth rate is visible): axes
#: mounted to about 1 mrad (seed 000 Table 2), scale within 1e-3. "mems": a consumer/industrial MEMS triad -- datasheet
#: cross-axis sensitivity of 1-2 %, nonlinearity of a few 1e-3 of full scale.
#: A prior from a file without "uncertainty" uses the term's typical change instead (what ages
#: between two calibrations, recal.model.terms).
DEFAULT_PRIOR_SIGMA: dict[str, dict[str, float]] = {
    "navigation": {
        "scale": 1e-3,  # rel
        "gyro.bias": 0.05,  # deg/h
        "accel.bias": 1e-3,  # g
        "misalignment": 1e-3,  # rad (seed 000 Table 2: up to 0.99 mrad)
        "quadratic": 5e-5,  # 1/g
    },
    "mems": {
        "scale": 3e-2,  # rel
        "gyro.bias": 1800.0,  # deg/h (0.5 deg/s turn-on bias)
        "accel.bias": 3e-2,  # g
        "misalignment": 1e-2,  # rad
        "quadratic": 1e-3,  # 1/g
    },
}
SENSOR_CLASSES = tuple(DEFAULT_PRIOR_SIGMA)


def _class_sigma(sensor_class: str, term_name: str, category: str) -> float | None:
    table = DEFAULT_PRIOR_SIGMA[sensor_class]
    return table.get(term_name, table.get(category))


def prior_sigma(
    layout: ParameterLayout,
    theta_prior: np.ndarray,
    typical: np.ndarray,
    given: Mapping[str, np.ndarray] | None,
    sensor_class: str,
    start_sigma: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, str]]:
    """(D,) 1-sigma of every parameter of the prior, and where each term's came from.

    ``given``: the prior file's uncertainty by term (NaN where unknown), or None for a prior
    derived from the data. Order: the file's value; for a file without it, the term's typical
    change (what ages between calibrations); for a data-derived prior, the sensor class default
    (:data:`DEFAULT_PRIOR_SIGMA`), else the typical change -- or, where ``start_sigma`` (D,) is
    finite (the data-derived start's own 1-sigma: the ellipsoid fit's, or what the nominal start
    may be off by; :class:`recal.solve.start.DataPrior`), that when it is larger.
    """
    sigma = np.array(typical, float)
    source: dict[str, str] = {}
    terms = [t for m in layout.models for t in m.terms]
    for term, sl in zip(terms, layout.term_slices().values(), strict=True):
        value = None if given is None else given.get(term.name)
        if value is not None and np.asarray(value).shape == sigma[sl].shape:
            v = np.asarray(value, float)
            sigma[sl] = np.where(np.isfinite(v), v, sigma[sl])
            source[term.name] = (
                "prior file" if np.all(np.isfinite(v)) else "prior file, gaps typical"
            )
            continue
        if given is not None:
            source[term.name] = "typical change (prior file has no uncertainty)"
            continue
        default = _class_sigma(sensor_class, term.name, term.category)
        if default is None:
            source[term.name] = "typical change"
            continue
        if term.relative_typical:
            sigma[sl] = default * np.abs(theta_prior[sl])
        else:
            sigma[sl] = default
        source[term.name] = f"{sensor_class} default"
        own = None if start_sigma is None else start_sigma[sl]
        if own is not None and np.any(own > sigma[sl]):
            sigma[sl] = np.fmax(sigma[sl], own)
            source[term.name] += " or the data-derived start's own 1-sigma, the larger"
    return sigma, source


def consider_covariance(
    problem: Problem,
    theta: np.ndarray,
    typical: np.ndarray,
    basis: np.ndarray,
    null: np.ndarray,
    sigma_prior: np.ndarray,
) -> np.ndarray:
    """(D, D) covariance the held directions' prior uncertainty adds (module docstring).

    ``basis`` (D, k) and ``null`` (D, h): estimated and held directions in typical-scaled
    coordinates (:class:`recal.solve.observability.ObservabilityReport`); ``sigma_prior`` (D,) the
    prior's 1-sigma per parameter.
    """
    D = theta.shape[0]
    if null.shape[1] == 0:
        return np.zeros((D, D))
    T = typical[:, None] * basis
    Th = typical[:, None] * null
    # prior covariance of the held coordinates u (theta = theta + Th u), parameters independent
    s = sigma_prior / typical
    cov_u = (null * s[:, None] ** 2).T @ null
    lam, vec = np.linalg.eigh(0.5 * (cov_u + cov_u.T))
    keep = lam > 1e-18 * max(float(lam.max()), 1e-300)
    if not keep.any():
        return np.zeros((D, D))
    du = vec[:, keep] * np.sqrt(lam[keep])  # (h, n) one column per sigma-point pair
    du = np.concatenate([du, -du], axis=1).T  # (2n, h)
    points = theta[None] + du @ Th.T
    r = problem.residuals(np.concatenate([theta[None], points]))
    dr = r[1:] - r[:1]  # (2n, R)
    if basis.shape[1]:
        J = jacobian(problem, theta, T.T)  # (R, k)
        dz = -np.linalg.lstsq(J, dr.T, rcond=None)[0].T  # (2n, k)
        e = dz @ T.T + du @ Th.T
    else:
        e = du @ Th.T
    return 0.5 * e.T @ e


#: Accelerometer white noise below this (micro-g/sqrt(Hz)) is navigation grade (quartz-flex
#: tens, MEMS 60-300): the class when no gyro is present.
NAVIGATION_ACCEL_DENSITY_UG = 60.0


def sensor_class(
    positions, layout: ParameterLayout, theta_prior: np.ndarray, earth_rate_contrast: float
) -> str:
    """Which :data:`DEFAULT_PRIOR_SIGMA` ("navigation" or "mems") a data-derived prior uses.

    From the gyro when present (its window means show Earth rate: a contrast of at least
    ``earth_rate_contrast``, :meth:`recal.model.positions.Positions.gyro_contrast`), else from the
    accelerometer's white-noise density (window-mean noise x sqrt(hold), in g via the prior
    scale); "mems" when neither can tell (the conservative choice). Only the defaults depend on
    it, never how the gyro is fitted.
    """
    seen = positions.gyro_contrast() if positions.has_gyro else None
    if seen is not None:
        return "navigation" if seen[0] >= earth_rate_contrast else "mems"
    cols = positions.columns
    slices = layout.term_slices()
    if positions.has_accel and "accel.scale" in slices and "start_s" in cols and "end_s" in cols:
        noise = positions.std_of_mean("accel")
        if noise is not None:
            hold = np.maximum(cols["end_s"] - cols["start_s"], 1e-9)
            scale = np.maximum(np.abs(theta_prior[slices["accel.scale"]]), 1e-300)
            density_ug = float(np.median(noise * np.sqrt(hold)[:, None] / scale) * 1e6)
            return "navigation" if density_ug < NAVIGATION_ACCEL_DENSITY_UG else "mems"
    return "mems"
