"""Rotation algebra on batches: unit quaternions [w, x, y, z] from rotation vectors (rad),
Hamilton products, rotating vectors back, the ordered pairwise product of a chain of
quaternions, and the cofactor matrices that carry cross products through a linear map.
Vectorised over any leading axes.
"""

from __future__ import annotations

import numpy as np


def cofactor3(M: np.ndarray) -> np.ndarray:
    """Cofactor matrices det(M) M^-T of a batch (..., 3, 3): (M a) x (M b) = cof(M) (a x b)."""
    c = np.empty_like(M)
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            c[..., i, j] = M[..., i1, j1] * M[..., i2, j2] - M[..., i1, j2] * M[..., i2, j1]
    return c


def rotvec_factor(angle: np.ndarray) -> np.ndarray:
    """sin(a/2)/a for rotation angles a (rad), with its series near 0: the vector part of the
    unit quaternion of a rotation vector is the vector times this."""
    small = angle < 1e-6
    return np.where(small, 0.5 - angle**2 / 48, np.sin(0.5 * angle) / np.where(small, 1.0, angle))


def quat_from_rotvec(phi: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), rad -> unit quaternions (..., 4) [w, x, y, z]."""
    angle = np.sqrt(np.einsum("...i,...i->...", phi, phi))
    k = rotvec_factor(angle)
    return np.concatenate([np.cos(0.5 * angle)[..., None], phi * k[..., None]], axis=-1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugates q* of quaternions (..., 4): the inverse rotation of a unit quaternion."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p q of quaternion arrays (..., 4)."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def rotate_back(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """C(q)^T v for quaternions (..., 4) and vectors (..., 3): a vector of the start frame in the
    end frame, when C(q) maps end-frame coordinates to start-frame ones."""
    w, u = q[..., :1], q[..., 1:]
    t = np.cross(u, v)
    return v - 2.0 * w * t + 2.0 * np.cross(u, t)


def rodrigues(phi: np.ndarray, v: np.ndarray) -> np.ndarray:
    """exp([phi]x) v for rotation vectors and vectors (..., 3)."""
    return rotate_back(quat_from_rotvec(-phi), v)


def chain_components(w, x, y, z):
    """Ordered Hamilton product over the last axis of quaternion components (..., G): pairwise,
    log2(G) vectorised steps. Returns the four components (...,)."""
    while w.shape[-1] > 1:
        if w.shape[-1] % 2:
            pad = [(0, 0)] * (w.ndim - 1) + [(0, 1)]
            w = np.pad(w, pad, constant_values=1.0)
            x, y, z = (np.pad(a, pad) for a in (x, y, z))
        aw, ax, ay, az = w[..., 0::2], x[..., 0::2], y[..., 0::2], z[..., 0::2]
        bw, bx, by, bz = w[..., 1::2], x[..., 1::2], y[..., 1::2], z[..., 1::2]
        w, x, y, z = (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        )
    return w[..., 0], x[..., 0], y[..., 0], z[..., 0]
