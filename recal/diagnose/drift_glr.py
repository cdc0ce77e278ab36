"""The generalised likelihood ratio of a step in one coefficient (docs/drift.md): its score and
Fisher information with the coefficients' own error projected out (:func:`gain_parts`,
:func:`score`), and the statistic T_n of a batch of score sequences (:func:`scan`). Shared by
the test, its null simulation and the suspects."""

from __future__ import annotations

import numpy as np


def gain_parts(
    F: np.ndarray, Lp: np.ndarray, n: int, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """G K (T, D, D) and diag(I) (T, D) for a step at each ``tau`` seen by window ``n``.

    With whitened windows the stacked covariance is I + B B^T, B = C Lp; by Woodbury its inverse
    is I - B (I + B^T B)^-1 B^T, so for a step signature a = C e_j on windows tau..n:
    z = a^T Sigma^-1 w = (S_n - S_tau) - G K S_n and I = G - G K G, with G = F_n - F_tau the
    information from tau on, K = Lp (I + Lp^T F_n Lp)^-1 Lp^T."""
    Mn = np.eye(Lp.shape[1]) + Lp.T @ F[n + 1] @ Lp
    K = Lp @ np.linalg.solve(Mn, Lp.T)
    G = F[n + 1][None] - F[tau]  # (T, D, D)
    GK = G @ K
    info = np.einsum("tdd->td", G) - np.einsum("tde,ted->td", GK, G)
    return GK, np.maximum(info, 0.0)


def score(
    S: np.ndarray, F: np.ndarray, Lp: np.ndarray, n: int, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Score z (T, D) and information diag(I) (T, D) of a step in each coefficient at each
    ``tau`` given windows 0..n, with the common coefficient error projected out (:func:`gain_parts`)."""
    GK, info = gain_parts(F, Lp, n, tau)
    z = (S[n + 1][None] - S[tau]) - GK @ S[n + 1]
    return z, info


def scan(
    S: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    seen: np.ndarray,
    lookback: int,
    where: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """T_n for a batch of score sequences S (P, M+1, D): (P, M) statistics and, with ``where``,
    (P, M) flat index t * D + j of the maximising (change window offset t, coefficient j)."""
    P, M, D = S.shape[0], S.shape[1] - 1, S.shape[2]
    stat = np.zeros((P, M))
    arg = np.zeros((P, M), int) if where else None
    for n in range(M):
        tau = np.arange(max(0, n - lookback + 1), n + 1)
        GK, info = gain_parts(F, Lp, n, tau)
        T = tau.size
        ok = seen & (info > 1e-12 * max(info.max(), 1e-300))
        inv = np.where(ok, 1.0 / np.where(ok, info, 1.0), 0.0).reshape(T * D)
        z = (S[:, n + 1, None, :] - S[:, tau, :]).reshape(P, T * D)
        z -= S[:, n + 1] @ GK.reshape(T * D, D).T
        z *= z
        z *= inv
        if arg is None:
            stat[:, n] = z.max(axis=1)
        else:
            arg[:, n] = np.argmax(z, axis=1)
            stat[:, n] = z[np.arange(P), arg[:, n]]
    return stat, arg
