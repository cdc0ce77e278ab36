"""The restricted likelihood of window residuals under bias wander (:mod:`recal.solve.wander`):
the banded precision of the state with candidate models batched (:class:`RestrictedLikelihood`),
the estimated directions it refits (:func:`reml_directions`) and the restricted -log L from its
moments (:func:`restricted_nll`), and the likelihood-ratio statistic of a given model
(:func:`wander_gain`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from recal.solve.wander_chain import (
    WanderSensitivity,
    WindowChain,
    as_sensitivity,
    gm_phi,
    observation_matrix,
    wander_state,
)
from recal.solve.wander_covariance import Whitening
from recal.solve.wander_model import TriadWander, WanderModel

#: The precision form needs 1 - Phi^2 > 0 between consecutive windows: two windows at the same
#: mid-time share their bias exactly, which is floored at this (a relative innovation variance
#: of 1e-12: a difference of 1e-6 sigma between them).
_MIN_INNOVATION = 1e-12
#: Candidates per banded factorisation: the stacked right-hand sides (windows x state axes x
#: (1 + estimated directions) per candidate) are kept under about this many numbers (32 MB).
_BATCH_NUMBERS = 4_000_000


# ---- the restricted likelihood: banded precision, candidates batched ------------------------
def reml_directions(jacobian: np.ndarray | None) -> np.ndarray | None:
    """The Jacobian's column space, scaled as the REML's log det uses it (left singular vectors
    times their singular values, null directions dropped)."""
    if jacobian is None or not jacobian.size:
        return None
    U, sv, _ = np.linalg.svd(jacobian, full_matrices=False)
    keep = sv > 1e-10 * sv.max()
    return U[:, keep] * sv[keep]


def restricted_nll(CC: np.ndarray, logdet: np.ndarray) -> np.ndarray:
    """Restricted -log L (B,) from Z^T C^-1 Z (B, c, c), Z = [r, J], and log det C (B,):
    0.5 (r' Pi r + log det C + log det J' C^-1 J), Pi the GLS residual maker."""
    value = CC[:, 0, 0] + logdet
    if CC.shape[1] > 1:
        A, b = CC[:, 1:, 1:], CC[:, 1:, 0]
        value = value - np.einsum("bi,bi->b", b, np.linalg.solve(A, b[..., None])[..., 0])
        value = value + np.linalg.slogdet(A)[1]
    return 0.5 * value


class RestrictedLikelihood:
    """The restricted -log L of standardised window residuals r ~ N(0, C) (with the Jacobian
    ``J`` of the estimated directions: each candidate refits them by GLS and pays log det of
    their information) for batches of candidate wander models.

    For a batch with the same state axes, C = I + H K H^T with K the axes' Gauss-Markov
    covariance (block-diagonal over axes, each a chain): its precision K^-1 is tridiagonal per
    axis, so A = K^-1 + H^T H is banded (upper band n in window-major order). log det C =
    log det A + log det K, Z^T C^-1 Z = Z^T Z - (H^T Z)^T A^-1 (H^T Z). One LAPACK pbtrf and one
    tbtrs do a whole batch: the candidates' A are stacked along the band (decoupled blocks)."""

    def __init__(
        self,
        r_std: np.ndarray,
        sigma: np.ndarray,
        sens: WanderSensitivity,
        chain: WindowChain,
        J: np.ndarray | None,
    ) -> None:
        Z = r_std[:, None] if J is None else np.column_stack([r_std, J])
        self.sens, self.sigma, self.chain = sens, sigma, chain
        self.Z = chain.pad(Z)  # (M, q, c)
        self.ZZ = Z.T @ Z
        self._moments: dict[tuple[tuple[str, int], ...], tuple[np.ndarray, np.ndarray]] = {}

    def moments(self, axes: tuple[tuple[str, int], ...]) -> tuple[np.ndarray, np.ndarray]:
        """(M, n, n) H_m^T H_m and (M n, c) H^T Z for these state axes (cached)."""
        if axes not in self._moments:
            H = observation_matrix(self.sens, self.sigma, self.chain, axes)
            HtH = np.einsum("mqa,mqb->mab", H, H)
            U = np.einsum("mqa,mqc->mac", H, self.Z).reshape(-1, self.Z.shape[2])
            self._moments[axes] = (HtH, U)
        return self._moments[axes]

    def model(self, model: Mapping[str, TriadWander]) -> float:
        """-log L (restricted) of one model."""
        axes, sig, tau = wander_state(model, self.sens)
        return float(self.batch(tuple(axes), sig[None], tau[None])[0])

    def candidates(
        self,
        fixed: Mapping[str, TriadWander],
        free: str,
        sigma: np.ndarray,
        tau: np.ndarray,
    ) -> np.ndarray:
        """-log L (B,) of ``fixed`` plus triad ``free`` at isotropic sigma (B,) and tau (B,)."""
        axes, sig, tf = wander_state({k: v for k, v in fixed.items() if k != free}, self.sens)
        B = len(sigma)
        axes = (*axes, (free, 0), (free, 1), (free, 2))
        sig_b = np.column_stack([np.tile(sig, (B, 1)), np.repeat(sigma[:, None], 3, axis=1)])
        tau_b = np.column_stack([np.tile(tf, (B, 1)), np.repeat(tau[:, None], 3, axis=1)])
        return self.batch(axes, sig_b, tau_b)

    def batch(self, axes: tuple[tuple[str, int], ...], sig: np.ndarray, tau: np.ndarray):
        """-log L (B,) of B models on the same state axes: sigma (B, n), tau_s (B, n)."""
        B, n = sig.shape
        if n == 0:
            return np.repeat(restricted_nll(self.ZZ[None], np.zeros(1)), B)
        HtH, U = self.moments(axes)
        M, c = self.chain.M, self.ZZ.shape[0]
        size = max(1, _BATCH_NUMBERS // (M * n * c))
        CC = np.empty((B, c, c))
        logdet = np.empty(B)
        for lo in range(0, B, size):  # chunks bound the memory, each chunk is one LAPACK call
            sl = slice(lo, min(B, lo + size))
            CC[sl], logdet[sl] = self._chunk(HtH, U, sig[sl], tau[sl])
        return restricted_nll(CC, logdet)

    def _chunk(self, HtH, U, sig, tau) -> tuple[np.ndarray, np.ndarray]:
        from scipy.linalg.lapack import dpbtrf, dtbtrs

        B, n = sig.shape
        M, c = self.chain.M, U.shape[1]
        phi = gm_phi(self.chain.gap, tau)  # (B, M, n): phi[m] links window m - 1 to m
        v = (sig * sig)[:, None, :] * np.maximum(1.0 - phi * phi, _MIN_INNOVATION)
        ahead = np.zeros_like(v)  # the next transition's pull on this window's state
        ahead[:, :-1] = phi[:, 1:] ** 2 / v[:, 1:]
        ab = np.zeros((n + 1, B, M, n))  # lower band storage: ab[i - j, j] = A[i, j]
        ab[0] = 1.0 / v + ahead + np.einsum("maa->ma", HtH)[None]
        for d in range(1, n):
            ab[d, :, :, : n - d] = np.diagonal(HtH, offset=-d, axis1=1, axis2=2)[None]
        ab[n, :, : M - 1, :] = -phi[:, 1:] / v[:, 1:]
        logdet_k = np.log(v).sum(axis=(1, 2))
        L, info = dpbtrf(ab.reshape(n + 1, B * M * n), lower=1)
        if info != 0:  # rounding broke positive definiteness in some block: each on its own
            if B == 1:
                return np.full((1, c, c), np.nan), np.full(1, np.inf)
            parts = [self._chunk(HtH, U, sig[i : i + 1], tau[i : i + 1]) for i in range(B)]
            return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        logdet_a = 2.0 * np.log(L[0].reshape(B, M * n)).sum(axis=1)
        rhs = np.tile(U.T, (1, B))  # (c, B M n): its transpose is the Fortran right-hand side
        Y, info = dtbtrs(L, rhs.T, uplo="L")
        Y = Y.T.reshape(c, B, M * n).transpose(1, 0, 2)  # (B, c, M n)
        CC = self.ZZ[None] - np.matmul(Y, Y.transpose(0, 2, 1))
        return CC, logdet_a + logdet_k


def wander_gain(
    r_std: np.ndarray,
    sigma: np.ndarray,
    sensitivity: Any,
    t: np.ndarray | None,
    model: WanderModel,
    jacobian: np.ndarray | None = None,
    sessions: np.ndarray | None = None,
) -> float:
    """2 x (restricted -log L with no wander - with ``model``): the likelihood-ratio statistic
    of a given wander model on a fit's standardised window residuals ``r_std`` (R,) (raw /
    ``sigma``), ``jacobian`` (R, k) the standardised residuals' Jacobian along the estimated
    directions (None: the plain likelihood). The statistic :func:`estimate_wander` tests,
    exact, computed through the model's Kalman innovations (:class:`Whitening`): linear in the
    windows, any correlation time (0, finite or infinite)."""
    sens = as_sensitivity(sensitivity)
    r_std = np.asarray(r_std, float)
    J = reml_directions(jacobian)
    Z = r_std[:, None] if J is None else np.column_stack([r_std, J])
    W = Whitening(sigma, sens, t, model, sessions)
    Wz = W.apply(Z.T)  # (c, R)
    with_model = restricted_nll((Wz @ Wz.T)[None], np.array([W.logdet]))[0]
    without = restricted_nll((Z.T @ Z)[None], np.zeros(1))[0]
    return float(2.0 * (without - with_model))
