"""The slew invariant's residuals: the gravity direction the integrated gyro carries from window
``first`` to window ``second`` against the one measured there (:func:`slew_residuals`, 2 per
slew, rad), their 1-sigma from the windows' noise (:func:`slew_sigma`), and the residual basis.
"""

from __future__ import annotations

import math

import numpy as np

from recal.detect.quaternions import rodrigues, rotate_back
from recal.detect.slew_data import Slews
from recal.detect.slew_rotation import DEG_H_TO_RAD_S, angle_random_walk_var, slew_rotations
from recal.model.reference import OMEGA_IE_RAD_S

#: Bound on P x slews x groups per batched evaluation (bounds the temporaries, ~25 MB each).
_BATCH_ELEMENTS = 1 << 20


def horizontal_basis(up: np.ndarray) -> np.ndarray:
    """(S, 2, 3) two unit vectors orthogonal to each direction ``up`` (S, 3) and to each other."""
    u = up / np.linalg.norm(up, axis=1, keepdims=True)
    helper = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(u, e1)], axis=1)


def slew_residuals(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    f_first: np.ndarray,
    f_second: np.ndarray,
    basis: np.ndarray,
    earth_rate: bool,
    zero_rate: np.ndarray | None = None,
    same_gyro: np.ndarray | None = None,
) -> np.ndarray:
    """Slew residuals (P, 2 S), rad: the gravity direction the integrated gyro predicts at
    window ``second`` against the measured one, ``u_meas x u_pred`` on ``basis`` (S, 2, 3).

    f_first / f_second: (P, S, 3) calibrated specific force of the two windows. With
    ``earth_rate`` the Earth's rotation over the slew is taken out, with the calibrated rest rate
    of window ``first`` as the Earth rate in its body frame (a gyro that sees Earth rate):
    u_(k+1) = C^T exp([w_k T]x) u_k. Without it, that rotation (Omega cos(lat) T, about north)
    is left in the noise budget (:func:`slew_sigma`); ``zero_rate`` is then the output taken as
    zero rate over each slew (:func:`slew_rotations`).
    ``same_gyro`` (P,): for each row, a row with the same gyro parameters (the integration is
    done once per distinct row: a Jacobian along accelerometer coefficients needs none); None:
    every row its own.
    Evaluated in batches over P so the temporaries stay bounded.
    """
    P, S = A.shape[0], len(slews)
    out = np.empty((P, S, 2))
    step = max(1, _BATCH_ELEMENTS // max(S * slews.sums.shape[1], 1))
    need, back = np.unique(np.arange(P) if same_gyro is None else same_gyro, return_inverse=True)
    back = back.reshape(-1)
    for a in range(0, need.size, step):  # a loop over batches of parameter vectors, not samples
        i = need[a : a + step]
        q_all, rest_all = slew_rotations(slews, gain[i], A[i], offset[i], zero_rate)
        rows = np.flatnonzero((back >= a) & (back < a + step))
        for c in range(0, rows.size, step):  # the rows that share these gyro parameters
            r = rows[c : c + step]
            q, rest = q_all[back[r] - a], rest_all[back[r] - a]
            u1 = f_first[r] / np.linalg.norm(f_first[r], axis=-1, keepdims=True)
            if earth_rate:
                u1 = rodrigues(rest * slews.duration_s[None, :, None], u1)
            pred = rotate_back(q, u1)
            u2 = f_second[r] / np.linalg.norm(f_second[r], axis=-1, keepdims=True)
            err = np.cross(u2, pred)
            out[r] = np.einsum("psi,sji->psj", err, basis)
    return out.reshape(P, 2 * S)


def slew_sigma(
    slews: Slews,
    gyro_std_in: np.ndarray | None,
    gyro_sem_in: np.ndarray | None,
    accel_sem_in: np.ndarray | None,
    f_first: np.ndarray,
    f_second: np.ndarray,
    basis: np.ndarray,
    earth_rate: bool,
    latitude_deg: float,
    excess_rad: float = 0.0,
) -> np.ndarray | None:
    """1-sigma (2 S,) of the slew residuals, rad, from the windows' noise; None without it.

    * gyro angle random walk: the per-sample gyro std (deg/h, mean of the two windows and of the
      axes) integrated over the slew's n samples: (u sigma dt)^2 n;
    * the two gravity directions: window-mean accel noise / |f|, window ``second`` projected on
      the residual basis, window ``first`` (seen through the rotation) its mean over axes;
    * Earth rate: with ``earth_rate`` the noise of the rest rate used for it, (u sem T)^2; without,
      the rotation left in, Omega cos(lat) T about an unknown north: (Omega cos(lat) T)^2 / 2
      per component.

    * ``excess_rad``: an unmodelled error per slew residual, estimated from the slews' own
      misfit (:func:`recal.solve.slew_fit.slew_excess`), 0 when they fit to their noise.

    gyro_std_in, gyro_sem_in, accel_sem_in: (M, 3) per window in input units.
    """
    if gyro_std_in is None or accel_sem_in is None:
        return None
    i, j, T = slews.first, slews.second, slews.duration_s
    var = angle_random_walk_var(slews, gyro_std_in)
    g1 = np.linalg.norm(f_first, axis=1)
    g2 = np.linalg.norm(f_second, axis=1)
    var = var + np.mean(accel_sem_in[i] ** 2, axis=1) / g1**2
    var2 = var[:, None] + np.einsum("sji,si->sj", basis**2, accel_sem_in[j] ** 2) / g2[:, None] ** 2
    var2 += excess_rad**2  # the unmodelled per-slew error, when the slews show one
    if earth_rate:
        if gyro_sem_in is not None:
            var2 += ((DEG_H_TO_RAD_S * T) ** 2 * np.mean(gyro_sem_in[i] ** 2, axis=1))[:, None]
    else:
        horizontal = OMEGA_IE_RAD_S * math.cos(math.radians(latitude_deg)) * T
        var2 += (horizontal**2 / 2.0)[:, None]
        if gyro_sem_in is not None:  # the zero-rate reference: the mean of the two windows
            ref = 0.25 * (
                np.mean(gyro_sem_in[i] ** 2, axis=1) + np.mean(gyro_sem_in[j] ** 2, axis=1)
            )
            var2 += ((DEG_H_TO_RAD_S * T) ** 2 * ref)[:, None]
    return np.sqrt(var2).reshape(-1)
