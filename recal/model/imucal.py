"""imucal's Ferraris calibration in this project's coefficients, to compare the two answers.

imucal (mad-lab-fau/imucal) writes ``acc_raw = K_a R_a a + b_a`` and
``gyr_raw = K_g R_g w + K_ga a + b_g``, with K diagonal, R with unit-norm rows (not orthogonal),
``w`` in deg/s and ``a`` in m/s^2 scaled so that |a| = 9.81 at rest (it assumes that value of
gravity wherever the unit was). This project writes ``N = diag(K) [(I + E) x + b]`` with a zero
diagonal of E, ``x`` in g (9.80665 m/s^2) or deg/h (docs/reference.md#models). So, with
``A = K R`` in output units per input unit:

    K_i = A_ii,   E_ij = A_ij / A_ii,   b = b_raw / K

where the accelerometer's input unit is imucal's "9.81 = local gravity": one g0 of specific
force is 9.81 / g_local imucal units, g_local in g0 (the latitude the comparison assumes; the
same latitude must be given to both fits, then it cancels). The gyro's K_ga becomes the
catalogue effect ``gyro.g_sensitivity`` (deg/h per g). The antisymmetric part of E depends on
which frame each tool calls the body's (imucal: the faces of its fixture; norms cannot see it),
so compare scale factors, biases and the symmetric sums of E.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.terms import MISALIGNMENT_INDEX

#: imucal's assumed gravity, m/s^2, and the standard gravity this project's g unit is.
IMUCAL_GRAVITY_MS2 = 9.81
G0_MS2 = 9.80665


def _matrix(doc: Mapping[str, Any], key: str) -> np.ndarray:
    try:
        m = np.asarray(doc[key], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise RecalInputError(f"imucal calibration: {key} missing or not numbers") from None
    if m.shape not in ((3, 3), (3,)):
        raise RecalInputError(f"imucal calibration: {key} must be 3x3 or 3 values")
    return m


def _split(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, E as the six entries of docs/reference.md#models) from A = diag(K) (I + E)."""
    K = np.diag(A).copy()
    E = A / K[:, None]
    return K, np.array([E[r, c] for r, c in MISALIGNMENT_INDEX])


def coefficients_from_imucal(doc: Mapping[str, Any], gravity_g: float) -> CoefficientSet:
    """A Ferraris calibration (imucal's JSON, as a dict) as a :class:`CoefficientSet`.

    ``gravity_g``: local gravity in g0 units where the session was recorded, as given to
    ``recal calibrate`` (:func:`recal.model.reference.normal_gravity_g`).
    """
    if doc.get("cal_type", "Ferraris") != "Ferraris":
        raise RecalInputError(f"imucal calibration: cal_type {doc.get('cal_type')!r}, not Ferraris")
    per_g0 = IMUCAL_GRAVITY_MS2 / gravity_g  # imucal accel units per g0 of specific force
    A_a = np.diag(_matrix(doc, "K_a"))[:, None] * _matrix(doc, "R_a") * per_g0
    K_a, E_a = _split(A_a)
    A_g = np.diag(_matrix(doc, "K_g"))[:, None] * _matrix(doc, "R_g") / 3600.0  # per deg/h
    K_g, E_g = _split(A_g)
    G = _matrix(doc, "K_ga") * per_g0 / K_g[:, None]  # deg/h per g
    return CoefficientSet(
        {
            "gyro.scale": K_g,
            "gyro.bias": _matrix(doc, "b_g") / K_g,
            "gyro.misalignment": E_g,
            "gyro.g_sensitivity": G.reshape(9),
            "accel.scale": K_a,
            "accel.bias": _matrix(doc, "b_a") / K_a,
            "accel.misalignment": E_a,
            "accel.quadratic": np.zeros(3),
        },
        metadata={"source": "imucal Ferraris calibration", "gravity_g": gravity_g},
    )
