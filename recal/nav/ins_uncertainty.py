"""The static INS error the coefficients' uncertainty allows: the seed layout a covariance is
given in (:data:`SEED_TERMS`), 1-sigma values from ``recal calibrate --json``
(:func:`sigma_from_doc`, :func:`seed_sigma`), the error's Jacobian over the coefficients
(:func:`error_jacobian`) and the 1-sigma horizontal error over time
(:func:`predict_from_uncertainty`). The model is :mod:`recal.nav.ins_static`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.terms import MISALIGNMENT_NAMES
from recal.nav.ins_static import DEFAULT_STEP_S, predict_static_error
from recal.nav.navigation import NMI_M


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


# ---------------------------------------------------------------------------- uncertainty
#: The seed layout a covariance is given in: gyro (K 3, b 3, E 6), accel (K 3, b 3, E 6, K2 3).
SEED_TERMS: tuple[str, ...] = (
    "gyro.scale", "gyro.bias", "gyro.misalignment",
    "accel.scale", "accel.bias", "accel.misalignment", "accel.quadratic",
)  # fmt: skip
#: Parameters per seed term kind.
SEED_SIZES = {"scale": 3, "bias": 3, "misalignment": 6, "quadratic": 3}
#: Parameters over :data:`SEED_TERMS` (the size of a covariance in that layout).
SEED_PARAMETERS = sum(SEED_SIZES[n.split(".")[1]] for n in SEED_TERMS)


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
        for key, size in SEED_SIZES.items():
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
        size = SEED_SIZES[n.split(".")[1]]
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
        size = SEED_SIZES[n.split(".")[1]]
        out.values[n] = vec[k : k + size].copy()
        k += size
    return out


def seed_sigma(sigma: CoefficientSet | Mapping[str, Any]) -> np.ndarray:
    """1-sigma per coefficient (a :class:`CoefficientSet` of sigmas, or the calibrate JSON's
    ``"uncertainty"`` layout) as a vector over :data:`SEED_TERMS`; missing or held entries are 0."""
    sig = sigma.values if isinstance(sigma, CoefficientSet) else sigma_from_doc(sigma)
    return np.concatenate(
        [np.nan_to_num(np.asarray(sig.get(n, np.zeros(SEED_SIZES[n.split(".")[1]])), float))
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
