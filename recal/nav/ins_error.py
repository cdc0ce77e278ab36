"""Predicted static navigation error from coefficient errors: the linear INS error model.

Public API (pure functions, no I/O, for the CLI, the benchmark and later the service):

* :func:`predict_static_error` ``(coeffs_used, coeffs_true, latitude_deg, height_m=0,
  attitude_rpy_deg=(0, 0, 0), hours=24, aligned=True) -> PredictedError``: the horizontal
  position error of a static INS that corrects its outputs with ``coeffs_used`` while the
  sensor follows ``coeffs_true``. ``PredictedError`` holds the north/east error curves (m) and
  ``final_nmi`` / ``max_nmi``, the sensor errors in the NED frame and the alignment error.
* :func:`predict_from_uncertainty` ``(sigma_or_doc, coeffs, latitude_deg, ...,
  covariance=None) -> UncertaintyPrediction``: the 1-sigma horizontal error (DRMS) the
  calibration uncertainty allows: 1-sigma per coefficient (a ``CoefficientSet`` of sigmas, or
  the ``"uncertainty"`` section of ``recal calibrate --json``; held coefficients, null there,
  count as exactly known) or a full covariance over the seed layout (gyro 12 then accel 15).
* :func:`describe_change` ``(old, new, ...)``: one sentence, "loading B instead of A changes the
  predicted 24 h static error from 4.5 to 1.2 nmi; the calibration uncertainty of B alone
  allows 0.3 nmi (1 sigma)" -- B is taken as the truth for A's error.

Model (psi-angle form, NED, height held, at rest; Titterton & Weston ch. 12, Benson 1975). The
computed attitude is C_c = (I - [psi x]) C_bn; with eps^n = C_bn dw^b the gyro error and del^n =
C_bn df^b the accelerometer error (rad/s, m/s^2)::

    d(dr)/dt = dv                                               (north, east, m)
    d(dv)/dt = -psi x f^n + del^n - 2 w_ie^n x dv - (g / R) dr  (Schuler loop)
    d(psi)/dt = -w_ie^n x psi - eps^n

The states are integrated exactly (matrix exponential over ``step_s``) for constant errors.
The sensor errors are exact differences at the IMU's attitude: ``dw^b = inverse(used,
forward(true, w^b)) - w^b``, the same for f. **They depend on how the IMU sits in the vessel**
(a scale-factor error of the axis that points up shows as a vertical accel error, one of an
axis pointing north as a north gyro error): ``attitude_rpy_deg`` is the IMU's roll, pitch, yaw
in NED, default level, x forward, heading 0 (x north, y east, z down).
With ``aligned=True`` the initial psi comes from running :func:`recal.nav.alignment.coarse_alignment`
on the same erroneous outputs, so the errors that alignment hides are hidden exactly as in
navigation (horizontal accel errors and the east gyro error, see :mod:`recal.nav.alignment`); the
north and down gyro errors remain and give the growing longitude error, the 24 h (Earth rate)
and Foucault modulations and the 84.4 min Schuler oscillation. ``aligned=False`` starts from
the true attitude (``recal navigate --attitude``).

Checked against :func:`recal.nav.navigation.navigate` on simulated data in the tests and the
benchmark.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.linalg import expm

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import ParameterLayout
from recal.model.reference import G0_M_S2, OMEGA_IE_RAD_S, normal_gravity_g, normal_gravity_m_s2
from recal.model.terms import MISALIGNMENT_NAMES
from recal.nav.alignment import coarse_alignment
from recal.nav.navigation import (
    DEG_H_TO_RAD_S,
    NMI_M,
    attitude_matrix,
    correction_models,
    radii_m,
    schuler_period_s,
)

DEFAULT_STEP_S = 60.0


@dataclass(frozen=True, eq=False)
class PredictedError:
    """Predicted static position error; arrays over ``time_s`` (from the navigation start, s).

    eps_ned_deg_h: gyro error in NED (deg/h); del_ned_ug: accelerometer error in NED (micro-g);
    psi0_rad: initial attitude error (psi, NED) left by the alignment (zeros when not aligned).
    """

    time_s: np.ndarray
    north_m: np.ndarray
    east_m: np.ndarray
    eps_ned_deg_h: np.ndarray
    del_ned_ug: np.ndarray
    psi0_rad: np.ndarray
    aligned: bool

    @property
    def horizontal_m(self) -> np.ndarray:
        return np.hypot(self.north_m, self.east_m)

    @property
    def final_m(self) -> float:
        return float(self.horizontal_m[-1])

    @property
    def max_m(self) -> float:
        return float(self.horizontal_m.max())

    @property
    def final_nmi(self) -> float:
        return self.final_m / NMI_M

    @property
    def max_nmi(self) -> float:
        return self.max_m / NMI_M


@dataclass(frozen=True, eq=False)
class UncertaintyPrediction:
    """1-sigma static position error over time from the coefficients' uncertainty (m)."""

    time_s: np.ndarray
    sigma_north_m: np.ndarray
    sigma_east_m: np.ndarray

    @property
    def sigma_horizontal_m(self) -> np.ndarray:
        """DRMS: sqrt(sigma_N^2 + sigma_E^2)."""
        return np.hypot(self.sigma_north_m, self.sigma_east_m)

    @property
    def final_nmi(self) -> float:
        return float(self.sigma_horizontal_m[-1]) / NMI_M

    @property
    def max_nmi(self) -> float:
        return float(self.sigma_horizontal_m.max()) / NMI_M


# ---------------------------------------------------------------------------- the error model
def error_dynamics(latitude_deg: float, height_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of x = [dr_N, dr_E, dv_N, dv_E, psi_N, psi_E, psi_D], u = [eps_N, eps_E, eps_D,
    del_N, del_E] (rad/s, m/s^2) at rest: dx/dt = A x + B u."""
    lat = math.radians(latitude_deg)
    sl, cl = math.sin(lat), math.cos(lat)
    W = OMEGA_IE_RAD_S
    g = normal_gravity_m_s2(latitude_deg, height_m)
    rm, rn = (float(r) + height_m for r in radii_m(lat))
    A = np.zeros((7, 7))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 0], A[2, 3], A[2, 5] = -g / rm, -2 * W * sl, g
    A[3, 1], A[3, 2], A[3, 4] = -g / rn, 2 * W * sl, -g
    A[4, 5] = -W * sl
    A[5, 4], A[5, 6] = W * sl, W * cl
    A[6, 5] = -W * cl
    B = np.zeros((7, 5))
    B[4, 0] = B[5, 1] = B[6, 2] = -1.0
    B[2, 3] = B[3, 4] = 1.0
    return A, B


@lru_cache(maxsize=16)
def _responses(latitude_deg: float, height_m: float, step_s: float, steps: int) -> np.ndarray:
    """(steps + 1, 2, 12): north/east error at each step per unit of [x0 (7); u (5)]."""
    A, B = error_dynamics(latitude_deg, height_m)
    M = np.zeros((12, 12))
    M[:7, :7], M[:7, 7:] = A, B
    Phi = expm(M * step_s)
    Z = np.eye(12)
    out = np.empty((steps + 1, 2, 12))
    out[0] = Z[:2]
    for k in range(steps):  # 12 x 12 products: 1440 steps for a day take a few ms
        Z = Phi @ Z
        out[k + 1] = Z[:2]
    out.setflags(write=False)
    return out


def propagate(
    eps_ned_rad_s: np.ndarray,
    del_ne_m_s2: np.ndarray,
    psi0_rad: np.ndarray,
    latitude_deg: float,
    height_m: float = 0.0,
    hours: float = 24.0,
    step_s: float = DEFAULT_STEP_S,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """time_s, north_m, east_m for constant sensor errors and an initial psi (zero dr, dv)."""
    steps = max(1, math.ceil(hours * 3600.0 / step_s))
    G = _responses(float(latitude_deg), float(height_m), float(step_s), steps)
    z = np.zeros(12)
    z[4:7] = psi0_rad
    z[7:10] = eps_ned_rad_s
    z[10:12] = np.asarray(del_ne_m_s2)[:2]
    ne = G @ z
    return np.arange(steps + 1) * step_s, ne[:, 0], ne[:, 1]


# ---------------------------------------------------------------------------- sensor errors
def static_inputs(
    C_bn: np.ndarray, latitude_deg: float, height_m: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """True gyro (deg/h) and accel (g) inputs of an IMU at rest with attitude C_bn."""
    lat = math.radians(latitude_deg)
    w_n = np.array([math.cos(lat), 0.0, -math.sin(lat)]) * OMEGA_IE_RAD_S / DEG_H_TO_RAD_S
    f_n = np.array([0.0, 0.0, -normal_gravity_g(latitude_deg, height_m)])
    return C_bn.T @ w_n, C_bn.T @ f_n


def corrected_static(
    coeffs_used: CoefficientSet,
    coeffs_true: CoefficientSet,
    C_bn: np.ndarray,
    latitude_deg: float,
    height_m: float = 0.0,
    temperature_c: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(w_true, f_true, w_corrected, f_corrected) in deg/h and g at rest with attitude C_bn."""
    w_b, f_b = static_inputs(C_bn, latitude_deg, height_m)
    temp = coeffs_used.t0_c if temperature_c is None else temperature_c
    ctx: dict[str, np.ndarray] = {
        "temperature_c": np.array([temp]),
        "temperature_rate_c_per_h": np.zeros(1),
        "time_h": np.zeros(1),
        "specific_force_g": f_b[None],
    }
    out = {}
    for sensor, x in (("gyro", w_b), ("accel", f_b)):
        m_true = correction_models(coeffs_true)[0 if sensor == "gyro" else 1]
        m_used = correction_models(coeffs_used)[0 if sensor == "gyro" else 1]
        theta_true = coeffs_true.to_vector(ParameterLayout((m_true,)))[None]
        theta_used = coeffs_used.to_vector(ParameterLayout((m_used,)))[None]
        raw = m_true.forward(theta_true, x[None], ctx)[0]
        out[sensor] = m_used.inverse(theta_used, raw, ctx)[0, 0]
    return w_b, f_b, out["gyro"], out["accel"]


def psi_from_attitudes(C_computed: np.ndarray, C_true: np.ndarray) -> np.ndarray:
    """psi (NED, rad) with C_computed = (I - [psi x]) C_true, to first order."""
    Psi = np.eye(3) - C_computed @ C_true.T
    Psi = 0.5 * (Psi - Psi.T)
    return np.array([Psi[2, 1], Psi[0, 2], Psi[1, 0]])


def predict_static_error(
    coeffs_used: CoefficientSet,
    coeffs_true: CoefficientSet,
    latitude_deg: float,
    height_m: float = 0.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    hours: float = 24.0,
    aligned: bool = True,
    step_s: float = DEFAULT_STEP_S,
) -> PredictedError:
    """Static position error of an INS correcting with ``coeffs_used`` (see the module doc)."""
    if not -90.0 <= latitude_deg <= 90.0:
        raise RecalInputError(f"latitude {latitude_deg} deg is outside [-90, 90]")
    C = attitude_matrix(*np.radians(np.asarray(attitude_rpy_deg, float)))
    w_b, f_b, w_c, f_c = corrected_static(coeffs_used, coeffs_true, C, latitude_deg, height_m)
    eps_n = C @ (w_c - w_b) * DEG_H_TO_RAD_S
    del_n = C @ (f_c - f_b) * G0_M_S2
    psi0 = psi_from_attitudes(coarse_alignment(f_c, w_c), C) if aligned else np.zeros(3)
    t, north, east = propagate(eps_n, del_n, psi0, latitude_deg, height_m, hours, step_s)
    return PredictedError(
        t, north, east, eps_n / DEG_H_TO_RAD_S, del_n / G0_M_S2 * 1e6, psi0, aligned
    )


# ---------------------------------------------------------------------------- uncertainty
#: The seed layout a covariance is given in: gyro (K 3, b 3, E 6), accel (K 3, b 3, E 6, K2 3).
SEED_TERMS: tuple[str, ...] = (
    "gyro.scale", "gyro.bias", "gyro.misalignment",
    "accel.scale", "accel.bias", "accel.misalignment", "accel.quadratic",
)  # fmt: skip
_SIZES = {"scale": 3, "bias": 3, "misalignment": 6, "quadratic": 3}
#: Parameters over :data:`SEED_TERMS` (the size of a covariance in that layout).
SEED_PARAMETERS = sum(_SIZES[n.split(".")[1]] for n in SEED_TERMS)


def sigma_from_doc(doc: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The ``"uncertainty"`` layout of ``recal calibrate --json`` (or a whole calibrate output)
    -> term name -> 1-sigma array; null (held) entries become 0: exactly the prior's value."""
    if "uncertainty" in doc and isinstance(doc["uncertainty"], Mapping):
        doc = doc["uncertainty"]
    out: dict[str, np.ndarray] = {}
    for sensor in ("gyro", "accel"):
        block = doc.get(sensor)
        if not isinstance(block, Mapping):
            continue
        for key, size in _SIZES.items():
            entry = block.get(key)
            if entry is None:
                continue
            items = (
                [entry.get(n) for n in MISALIGNMENT_NAMES] if isinstance(entry, Mapping) else entry
            )
            if len(items) != size:
                raise RecalInputError(f"uncertainty {sensor}.{key} must have {size} values")
            try:
                arr = np.array([0.0 if v is None else float(v) for v in items])
            except (TypeError, ValueError):
                raise RecalInputError(f"uncertainty {sensor}.{key} must be numbers") from None
            if not np.all(np.isfinite(arr)) or (arr < 0).any():
                raise RecalInputError(f"uncertainty {sensor}.{key} must be finite and >= 0")
            out[f"{sensor}.{key}"] = arr
    if not out:
        raise RecalInputError("no uncertainties found (expected 'gyro' and/or 'accel' entries)")
    return out


def error_jacobian(
    coeffs: CoefficientSet,
    latitude_deg: float,
    height_m: float = 0.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    hours: float = 24.0,
    aligned: bool = True,
    step_s: float = DEFAULT_STEP_S,
) -> tuple[np.ndarray, np.ndarray]:
    """time_s and J (K + 1, 2, 27): d(north, east error)/d(coefficient) over the seed layout,
    by central differences of :func:`predict_static_error` (linear to first order)."""
    vec = np.concatenate([np.asarray(coeffs.values[n], float) for n in SEED_TERMS])
    steps = []
    for n in SEED_TERMS:
        size = _SIZES[n.split(".")[1]]
        if n.endswith("scale"):  # 1 ppm of the scale factor
            steps.append(1e-6 * np.abs(np.asarray(coeffs.values[n], float)))
        else:  # 1e-3 deg/h for a gyro bias; 1e-6 g, 1e-6 rad, 1e-6 /g for the others
            steps.append(np.full(size, 1e-3 if n == "gyro.bias" else 1e-6))
    h = np.concatenate(steps)
    cols = []
    t = None
    for i in range(vec.size):
        pm = []
        for sgn in (1.0, -1.0):
            v = vec.copy()
            v[i] += sgn * h[i]
            used = _with_vector(coeffs, v)
            p = predict_static_error(
                used, coeffs, latitude_deg, height_m, attitude_rpy_deg, hours, aligned, step_s
            )
            t = p.time_s
            pm.append(np.stack([p.north_m, p.east_m], axis=1))
        cols.append((pm[0] - pm[1]) / (2 * h[i]))
    return t, np.stack(cols, axis=-1)


def _with_vector(coeffs: CoefficientSet, vec: np.ndarray) -> CoefficientSet:
    out = coeffs.copy()
    k = 0
    for n in SEED_TERMS:
        size = _SIZES[n.split(".")[1]]
        out.values[n] = vec[k : k + size].copy()
        k += size
    return out


def seed_sigma(sigma: CoefficientSet | Mapping[str, Any]) -> np.ndarray:
    """1-sigma per coefficient (a :class:`CoefficientSet` of sigmas, or the calibrate JSON's
    ``"uncertainty"`` layout) as a vector over :data:`SEED_TERMS`; missing or held entries are 0."""
    sig = sigma.values if isinstance(sigma, CoefficientSet) else sigma_from_doc(sigma)
    return np.concatenate(
        [np.nan_to_num(np.asarray(sig.get(n, np.zeros(_SIZES[n.split(".")[1]])), float))
         for n in SEED_TERMS]
    )  # fmt: skip


def predict_from_uncertainty(
    sigma: CoefficientSet | Mapping[str, Any] | None,
    coeffs: CoefficientSet,
    latitude_deg: float,
    height_m: float = 0.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    hours: float = 24.0,
    aligned: bool = True,
    covariance: np.ndarray | None = None,
    step_s: float = DEFAULT_STEP_S,
) -> UncertaintyPrediction:
    """1-sigma static position error allowed by the coefficients' uncertainty.

    ``sigma``: 1-sigma per coefficient, a :class:`CoefficientSet` of sigmas or the calibrate
    JSON's ``"uncertainty"`` layout (independent errors), or None with ``covariance``: (27, 27)
    in the :data:`SEED_TERMS` order (or (12, 12) for the gyro alone). ``coeffs`` is the nominal
    set the Jacobian is taken at.
    """
    full = coeffs.copy()
    for n in SEED_TERMS:
        if full.get(n) is None:
            raise RecalInputError(f"coefficients lack {n}: the prediction needs both triads")
    t, J = error_jacobian(full, latitude_deg, height_m, attitude_rpy_deg, hours, aligned, step_s)
    if covariance is not None:
        cov = np.asarray(covariance, float)
        D = J.shape[-1]
        if cov.shape == (12, 12):
            cov = np.pad(cov, ((0, D - 12), (0, D - 12)))
        if cov.shape != (D, D):
            raise RecalInputError(f"covariance must be 12 x 12 or {D} x {D}, not {cov.shape}")
        var = np.einsum("kai,ij,kaj->ka", J, cov, J)
    else:
        if sigma is None:
            raise RecalInputError("give 1-sigma values or a covariance")
        s = seed_sigma(sigma)
        var = np.einsum("kai,i->ka", J * J, s * s)
    sd = np.sqrt(np.maximum(var, 0.0))
    return UncertaintyPrediction(t, sd[:, 0], sd[:, 1])


def describe_change(
    old: CoefficientSet,
    new: CoefficientSet,
    latitude_deg: float,
    height_m: float = 0.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    hours: float = 24.0,
    sigma_new: CoefficientSet | Mapping[str, Any] | None = None,
    old_name: str = "A",
    new_name: str = "B",
) -> str:
    """One sentence comparing the predicted static errors of loading ``new`` instead of
    ``old``, taking ``new`` as the truth (its own error is then its uncertainty, ``sigma_new``,
    taken as independent 1-sigmas)."""
    if sigma_new is None:
        p_old = predict_static_error(old, new, latitude_deg, height_m, attitude_rpy_deg, hours)
        return (
            f"with {new_name} as the truth, {old_name} gives a predicted {hours:g} h static "
            f"error of {p_old.final_nmi:.2f} nmi (max {p_old.max_nmi:.2f}); loading {new_name} "
            f"removes it (0 nmi if {new_name} is exact)"
        )
    cov = np.diag(seed_sigma(sigma_new) ** 2)
    impact = navigation_impact(new, cov, latitude_deg, height_m, attitude_rpy_deg, hours,
                               old=old, from_version=old_name)  # fmt: skip
    return impact.sentence(new_name)


def schuler_amplitude_m(
    time_s: np.ndarray, error_m: np.ndarray, latitude_deg: float, height_m: float = 0.0
) -> float:
    """Amplitude of the Schuler (84.4 min) oscillation in an error curve, m.

    The curve minus its moving mean over one Schuler period (which removes that oscillation
    and keeps the slower 24 h and Foucault terms) is the Schuler part; amplitude = sqrt(2) x
    its RMS. NaN for a curve shorter than two periods.
    """
    t = np.asarray(time_s, float)
    x = np.asarray(error_m, float)
    if t.size < 3:
        return float("nan")
    dt = float(np.median(np.diff(t)))
    n = max(1, round(schuler_period_s(latitude_deg, height_m) / dt))
    if x.size < 2 * n:
        return float("nan")
    c = np.concatenate(([0.0], np.cumsum(x)))
    mean = (c[n:] - c[:-n]) / n  # mean over [i, i + n)
    part = x[n // 2 : n // 2 + mean.size] - mean
    return float(math.sqrt(2.0) * np.sqrt(np.mean(part * part)))


# ---------------------------------------------------------------------------- a version's impact
@dataclass(frozen=True)
class NavigationImpact:
    """What loading a calibration version is predicted to do to a static INS (all in metres).

    ``error_m_1sigma``: the 1-sigma (DRMS) horizontal error after ``hours`` that this version's
    own uncertainty allows. ``old_error_m``: the error the previously accepted version leaves if
    this one is the truth (their difference, propagated); ``accepted_error_m_1sigma``: the
    accepted version's own 1-sigma figure, for a like-for-like comparison. ``exact`` names the
    coefficients counted as exactly known (held with no earlier uncertainty, or not calibrated).
    """

    latitude_deg: float
    height_m: float
    attitude_rpy_deg: tuple[float, float, float]
    hours: float
    error_m_1sigma: float
    max_error_m_1sigma: float
    exact: tuple[str, ...] = ()
    from_version: int | str | None = None  # a stored version, or a file name
    old_error_m: float | None = None
    accepted_error_m_1sigma: float | None = None

    @property
    def error_nmi_1sigma(self) -> float:
        return self.error_m_1sigma / NMI_M

    @property
    def significant(self) -> bool:
        """The accepted version's error (if this one is right) exceeds this one's 1-sigma: the
        recalibration changes the predicted error by more than it is unsure of."""
        return self.old_error_m is not None and self.old_error_m > self.error_m_1sigma

    def worse_than_accepted(self, margin_nmi: float = 0.0) -> bool:
        """True when this version's 1-sigma error exceeds the accepted one's by ``margin_nmi``."""
        if self.accepted_error_m_1sigma is None:
            return False
        return self.error_m_1sigma > self.accepted_error_m_1sigma + margin_nmi * NMI_M

    def sentence(self, this: str = "this version") -> str:
        h = f"{self.hours:g} h"
        text = (
            f"the calibration uncertainty of {this} allows a {h} static error of "
            f"{self.error_nmi_1sigma:.2f} nmi (1 sigma) at {self.latitude_deg:.1f} deg"
        )
        if self.from_version is not None and self.old_error_m is not None:
            v = self.from_version
            name = f"version {v}" if isinstance(v, int) else v
            text = (
                f"loading {this} instead of {name} changes the predicted {h} static error "
                f"from {self.old_error_m / NMI_M:.2f} to {self.error_nmi_1sigma:.2f} nmi; " + text
            )
            if not self.significant:
                text += (
                    f"; the two differ by less than this uncertainty: {name} is as good, "
                    "within what this calibration can tell"
                )
        if self.exact:
            text += f" ({len(self.exact)} coefficient(s) counted as exact: {', '.join(self.exact)})"
        return text

    def to_json_dict(self) -> dict[str, Any]:
        nmi = self.error_nmi_1sigma
        change = None
        if self.from_version is not None and self.old_error_m is not None:
            old = self.old_error_m / NMI_M
            accepted = self.accepted_error_m_1sigma
            change = {
                "from_version": self.from_version,
                "old_error_nmi": old,
                "new_error_nmi": nmi,
                "delta_nmi": nmi - old,
                "significant": self.significant,
                "accepted_error_nmi_1sigma": None if accepted is None else accepted / NMI_M,
            }
        return {
            "latitude_deg": self.latitude_deg,
            "height_m": self.height_m,
            "attitude_rpy_deg": list(self.attitude_rpy_deg),
            "hours": self.hours,
            "static_24h_error_m_1sigma": self.error_m_1sigma,
            "static_24h_error_nmi_1sigma": nmi,
            "max_error_nmi_1sigma": self.max_error_m_1sigma / NMI_M,
            "counted_as_exact": list(self.exact),
            "change": change,
            "summary": self.sentence(),
        }


def seed_covariance(
    term_slices: Mapping[str, slice],
    covariance: np.ndarray,
    fallback_sigma: Mapping[str, np.ndarray] | None = None,
) -> tuple[np.ndarray, list[str]]:
    """A fit's flat covariance re-indexed to the (27, 27) :data:`SEED_TERMS` layout.

    Parameters the fit held (zero variance) or lacks take ``fallback_sigma`` (term name -> 1-sigma,
    e.g. the version they were held at) on the diagonal; those still without an uncertainty are
    returned by flat name ("accel.quadratic.K2x") as counted exact.
    """
    cov_in = np.asarray(covariance, float)
    idx = np.concatenate(
        [np.arange(term_slices[n].start, term_slices[n].stop) if n in term_slices
         else np.full(_SIZES[n.split(".")[1]], -1) for n in SEED_TERMS]
    )  # fmt: skip
    have = idx >= 0
    cov = np.zeros((idx.size, idx.size))
    cov[np.ix_(have, have)] = cov_in[np.ix_(idx[have], idx[have])]
    fallback = np.concatenate(
        [np.nan_to_num(np.asarray((fallback_sigma or {}).get(n, np.zeros(_SIZES[n.split(".")[1]])),
                                  float)) for n in SEED_TERMS]
    )  # fmt: skip
    known = np.diag(cov) > 0
    fill = ~known & (fallback > 0)
    cov[fill, fill] = fallback[fill] ** 2
    names = [f"{t.name}.{p}" for t in _seed_term_objects() for p in t.params]
    exact = [nm for nm, k, f in zip(names, known, fill, strict=True) if not (k or f)]
    return cov, exact


def navigation_impact(
    new: CoefficientSet,
    covariance: np.ndarray,
    latitude_deg: float,
    height_m: float = 0.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    hours: float = 24.0,
    exact: Sequence[str] = (),
    old: CoefficientSet | None = None,
    from_version: int | str | None = None,
    accepted_error_m_1sigma: float | None = None,
    step_s: float = DEFAULT_STEP_S,
) -> NavigationImpact:
    """The predicted navigation impact of loading ``new`` (both triads, (27, 27) covariance in
    :data:`SEED_TERMS` order), and of replacing ``old`` (version ``from_version``) by it."""
    att = tuple(float(a) for a in attitude_rpy_deg)
    u = predict_from_uncertainty(
        None, new, latitude_deg, height_m, att, hours, covariance=covariance, step_s=step_s
    )
    old_m = None
    if old is not None:
        old_m = predict_static_error(old, new, latitude_deg, height_m, att, hours, True, step_s)
        old_m = old_m.final_m
    sd = u.sigma_horizontal_m
    return NavigationImpact(
        latitude_deg, height_m, att, hours, float(sd[-1]), float(sd.max()), tuple(exact),
        from_version, old_m, accepted_error_m_1sigma,
    )  # fmt: skip


def complete_seed_set(
    coeffs: CoefficientSet, fallback: CoefficientSet | None = None
) -> tuple[CoefficientSet, list[str]]:
    """``coeffs`` with every :data:`SEED_TERMS` entry: missing ones from ``fallback``, else the
    term's neutral value (no error). Returns the set and the names filled in."""
    neutral = {t.name: np.asarray(t.neutral, float) for t in _seed_term_objects()}
    out = coeffs.copy()
    filled = []
    for n in SEED_TERMS:
        if out.get(n) is None:
            v = None if fallback is None else fallback.get(n)
            out.values[n] = np.array(neutral[n] if v is None else v, float)
            filled.append(n)
    return out, filled


@lru_cache(maxsize=1)
def _seed_term_objects() -> tuple[Any, ...]:
    """The seed model's terms in :data:`SEED_TERMS` order."""
    from recal.model.terms import seed_terms

    terms = {t.name: t for s in ("gyro", "accel") for t in seed_terms(s)}
    return tuple(terms[n] for n in SEED_TERMS)
