"""The gauge of a fit with slews: both triads' frames turned together until the accelerometer's
antisymmetric misalignment is zero (:func:`in_accel_frame`), to compare a simulated truth with
such a fit.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def in_accel_frame(theta: np.ndarray, layout: Any) -> np.ndarray:
    """Coefficients (flat, ``layout``: a ParameterLayout) with both triads' frames turned
    together until the accelerometer's antisymmetric misalignment is zero.

    That common rotation is invisible without an outside reference, so a fit with slews holds
    it (the accelerometer frame is the reference, its antisymmetric part held at a zero prior):
    compare a simulated truth with such a fit in this gauge. Exact (a fixed-point on the
    rotation), with each row's diagonal returned to the scale factor and bias.
    """
    from scipy.linalg import expm

    from recal.model.terms import MISALIGNMENT_INDEX

    th, sl = np.array(theta, float), layout.term_slices()
    rows, cols = zip(*MISALIGNMENT_INDEX, strict=True)
    A = {}
    for s in ("gyro", "accel"):
        E = np.zeros((3, 3))
        E[rows, cols] = th[sl[f"{s}.misalignment"]]
        A[s] = np.eye(3) + E
    Rc = np.eye(3)
    for _ in range(8):
        Aa = A["accel"] @ Rc
        Ea = Aa / np.diag(Aa)[:, None]
        W = 0.5 * (Ea - Ea.T)
        w = np.array([W[2, 1], W[0, 2], W[1, 0]])
        Rc = Rc @ expm(-np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]))
    for s in ("gyro", "accel"):
        Ap = A[s] @ Rc
        d = np.diag(Ap)
        th[sl[f"{s}.misalignment"]] = (Ap / d[:, None])[rows, cols]
        th[sl[f"{s}.scale"]] *= d
        th[sl[f"{s}.bias"]] /= d
    return th
