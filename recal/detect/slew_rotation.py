"""The gyro integrated over each slew, batched over parameter vectors: per-group rotation
vectors from the group sums (the algebra in :mod:`recal.detect.slew_groups`), their quaternions chained
by a pairwise product (:func:`slew_rotations`), the summed rotation vector that keeps whole turns
(:func:`integrated_rotvec`), and a sample-by-sample reference integration for checks.
"""

from __future__ import annotations

import math

import numpy as np

from recal.detect.quaternions import (
    chain_components,
    cofactor3,
    quat_from_rotvec,
    quat_multiply,
    rotvec_factor,
)
from recal.detect.slew_data import Slews
from recal.model.error_model import inv3

#: deg/h -> rad/s (the gyro model's input unit to the integration's).
DEG_H_TO_RAD_S = math.radians(1.0) / 3600.0


# ---- integration, batched over parameter vectors ----------------------------------------------
def _group_rotvecs(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    zero_rate: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-group rotation vectors (P, S, 3, G), rad, and the rest rate (P, S, 3), rad/s, of
    :func:`slew_rotations` (see there for the arguments)."""
    P, S = A.shape[0], len(slews)
    Ainv = inv3(A)[:, None]  # (P, 1, 3, 3)
    Mm = DEG_H_TO_RAD_S * Ainv / gain[:, :, None, :]  # (P, S|1, 3, 3): column j / gain_j
    rest = (Ainv @ (slews.reference[None] / gain - offset)[..., None])[..., 0]
    rest = DEG_H_TO_RAD_S * np.broadcast_to(rest, (P, S, 3))  # (P, S, 3) rad/s
    Mb = np.broadcast_to(Mm, (P, S, 3, 3))
    if zero_rate is None:
        c = (rest * slews.period_s)[..., None]  # per-sample rest increment, rad, (P, S, 3, 1)
    else:
        rho = (np.asarray(zero_rate, float) - slews.reference) * slews.period_s  # (S, 3)
        c = -(Mb @ rho[None, :, :, None])  # (P, S, 3, 1)
        rest = np.zeros_like(rest)
    phi = Mb @ slews.sums.transpose(0, 2, 1)  # (P, S, 3, G)
    phi += slews.group_samples[None, :, None, :] * c
    mw = Mb @ slews.weighted.transpose(0, 2, 1)
    phi[:, :, 0] += 0.5 * (mw[:, :, 1] * c[:, :, 2] - mw[:, :, 2] * c[:, :, 1])
    phi[:, :, 1] += 0.5 * (mw[:, :, 2] * c[:, :, 0] - mw[:, :, 0] * c[:, :, 2])
    phi[:, :, 2] += 0.5 * (mw[:, :, 0] * c[:, :, 1] - mw[:, :, 1] * c[:, :, 0])
    phi += cofactor3(Mb) @ slews.cross.transpose(0, 2, 1)
    return phi, rest


def slew_rotations(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    zero_rate: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrated rotation and rest rate per parameter vector and slew.

    The gyro model N = gain * (A w + offset) (w in deg/h) with gain and offset of shape (P, 1, 3)
    or (P, S, 3) (per slew: the context of its first window) and A (P, 3, 3). Returns the
    quaternions (P, S, 4) of the rotation from the body frame at the end of window ``first`` to
    the one at the start of window ``second`` (C(q) maps the latter's coordinates to the
    former's), and the calibrated rest rate of window ``first`` (P, S, 3) in rad/s.

    ``zero_rate`` (S, 3), output units: the output taken as zero rate over each slew instead of
    the model's bias (for a gyro blind to Earth rate, whose bias wanders between windows by more
    than the model's constant bias can follow: the mean output of the slew's two windows is the
    best estimate of the bias during it). The increments are then shifted exactly to that
    reference (``c = -M rho``, rho = (zero_rate - reference) dt) and the rest rate is zero.
    Component-major inside: three (P x S) batches of 3x3 by 3xG matrix products, then
    elementwise work on (P, S, G) arrays.
    """
    phi, rest = _group_rotvecs(slews, gain, A, offset, zero_rate)
    angle = np.sqrt(np.einsum("psig,psig->psg", phi, phi))
    k = rotvec_factor(angle)
    w, x, y, z = chain_components(np.cos(0.5 * angle), *(phi[:, :, i] * k for i in range(3)))
    return np.stack([w, x, y, z], axis=-1), rest


def picked_rotations(
    slews: Slews,
    pick: np.ndarray,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    zero_rate: np.ndarray | None = None,
) -> tuple[Slews, np.ndarray, np.ndarray]:
    """The slews at positions ``pick`` (K,), with their integrated rotations (P, K, 4) and rest
    rates (P, K, 3), rad/s, from :func:`slew_rotations`; the model arrays are those for all the
    slews (gain and offset per slew or shared, zero_rate (S, 3) or None)."""
    sub = slews.subset(pick)
    g = gain if gain.shape[1] == 1 else gain[:, pick]
    o = offset if offset.shape[1] == 1 else offset[:, pick]
    z = None if zero_rate is None else np.asarray(zero_rate)[pick]
    q, rest = slew_rotations(sub, g, A, o, z)
    return sub, q, rest


def angle_random_walk_var(
    slews: Slews, gyro_std_in: np.ndarray, pick: np.ndarray | slice = slice(None)
) -> np.ndarray:
    """Variance of the integrated angle per component, rad^2, of the slews at ``pick``: the
    per-sample gyro std (deg/h, (M, 3) per window; mean of the slew's two windows and of the
    axes) integrated over the slew's n samples, (u sigma dt)^2 n."""
    i, j = slews.first[pick], slews.second[pick]
    s_rate = 0.5 * (np.mean(gyro_std_in[i] ** 2, axis=1) + np.mean(gyro_std_in[j] ** 2, axis=1))
    return (DEG_H_TO_RAD_S * slews.period_s) ** 2 * s_rate * slews.samples[pick]


def integrated_rotvec(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    zero_rate: np.ndarray | None = None,
) -> np.ndarray:
    """(P, S, 3) sum of the group rotation vectors over each slew, rad: the rotation vector of a
    turn about a fixed axis with its whole revolutions kept (a quaternion forgets them)."""
    phi, _ = _group_rotvecs(slews, gain, A, offset, zero_rate)
    return phi.sum(axis=-1)


def integrate_samples(rates_rad_s: np.ndarray, period_s: float) -> np.ndarray:
    """Reference integration of one slew at the full rate, for tests and checks: rates (n, 3) in
    rad/s, each sample held for one period, composed sample by sample (a sequential loop: slow,
    never on a hot path). Returns the quaternion (4,) of C(start <- end)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for r in quat_from_rotvec(np.asarray(rates_rad_s, float) * period_s):
        q = quat_multiply(q, r)
    return q
