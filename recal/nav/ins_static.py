"""The static INS error from coefficient errors: the linear psi-angle model (the overview and its
equations are in :mod:`recal.nav.ins_error`).

:func:`predict_static_error` gives the horizontal position error of a static INS that corrects
its outputs with one coefficient set while the sensor follows another: the sensor errors in NED at
the IMU's attitude (:func:`static_inputs`, :func:`corrected_static`), the alignment's initial psi
(:func:`psi_from_attitudes`), and the error states integrated exactly (:func:`error_dynamics`,
:func:`propagate`). :func:`schuler_amplitude_m` measures the Schuler oscillation in a curve.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import ParameterLayout
from recal.model.reference import G0_M_S2, OMEGA_IE_RAD_S, normal_gravity_g, normal_gravity_m_s2
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
