"""The covariance bias wander adds to the window residuals (:mod:`recal.solve.wander`): the
whitening by a Kalman filter's standardised innovations (:class:`Whitening`, one banded solve),
the covariance a problem carries (:class:`WanderCovariance`), the drift test's innovations
(:func:`innovations`), and the dense references for small problems and tests
(:func:`correlation`, :func:`wander_covariance`, :func:`whitener`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from recal.solve.wander_chain import (
    WanderSensitivity,
    as_sensitivity,
    gm_phi,
    observation_matrix,
    wander_state,
    window_chain,
)
from recal.solve.wander_model import WanderModel

#: The dense whitening refuses a covariance whose smallest eigenvalue falls below this.
_JITTER = 1e-10


# ---- the whitening: Kalman innovations, one banded solve --------------------------------------
class Whitening:
    """W with W^T W = C^-1, C = I + D^-1 Sigma_w D^-1 the covariance of the standardised window
    residuals r / sigma (:meth:`apply`), and log det C: the Kalman filter's innovations.

    The filter's gains depend on the model alone (one pass over the windows, each step a few
    products of n x n matrices, n <= 6); the innovations of a batch of residual vectors are then
    x_m = F_m x_{m-1} + K_m z_m, F_m = (I - K_m H_m) Phi_m, a block-bidiagonal system solved for
    every vector at once (LAPACK tbtrs, band 2n - 1), and w_m = chol(S_m)^-1 (z_m - H_m Phi_m
    x_{m-1}). W is the inverse Cholesky factor of C with the residuals in window-time order (a
    residual's whitened value is its innovation: it depends on the windows before it), put back
    in the residuals' own order. Time and memory linear in the windows."""

    def __init__(
        self,
        sigma: np.ndarray,
        sensitivity: Any,
        t: np.ndarray | None,
        model: WanderModel,
        sessions: np.ndarray | None = None,
    ) -> None:
        sens = as_sensitivity(sensitivity)
        sigma = np.asarray(sigma, float)
        self.n_residuals = sens.n_residuals
        chain = window_chain(sens, t, sessions)
        axes, sig, tau = wander_state(model.triads, sens)
        self.chain, self.n = chain, len(axes)
        if not axes:
            self.logdet = 0.0
            return
        H = observation_matrix(sens, sigma, chain, axes)  # (M, q, n)
        phi = gm_phi(chain.gap, tau)  # (M, n)
        M, q, n = H.shape
        gains = np.empty((M, n, q))
        linv = np.empty((M, q, q))
        eye_q, eye_n = np.eye(q), np.eye(n)
        s2 = sig * sig
        P = np.zeros((n, n))
        for m in range(M):  # the Riccati recursion: one small step per window (n <= 6, q <= 3)
            f = phi[m]
            P = f[:, None] * P * f[None, :] + np.diag(s2 * (1.0 - f * f))
            Hm = H[m]
            PHt = P @ Hm.T
            L = np.linalg.cholesky(Hm @ PHt + eye_q)
            Li = np.linalg.inv(L)
            G = PHt @ (Li.T @ Li)  # P H^T S^-1
            IKH = eye_n - G @ Hm
            P = IKH @ P @ IKH.T + G @ G.T  # Joseph form: stays symmetric positive definite
            gains[m], linv[m] = G, Li
        self.H, self.phi, self.gains, self.linv = H, phi, gains, linv
        self.logdet = float(-2.0 * np.sum(np.log(np.diagonal(linv, axis1=1, axis2=2))))
        # F_m below the unit diagonal, lower band storage: row (m, a), column (m - 1, b) sits at
        # offset n + a - b
        F = (eye_n - np.einsum("mnq,mqk->mnk", gains, H)) * phi[:, None, :]
        ab = np.zeros((2 * n, M, n))
        for a in range(n):
            for b in range(n):
                ab[n + a - b, : M - 1, b] = -F[1:, a, b]
        self._band = np.asfortranarray(ab.reshape(2 * n, M * n))

    def apply(self, z: np.ndarray) -> np.ndarray:
        """(P, R) standardised residuals -> (P, R) whitened (unit covariance under the model)."""
        z = np.asarray(z, float)
        if self.n == 0:
            return z
        from scipy.linalg.lapack import dtbtrs

        chain, n = self.chain, self.n
        P, M = z.shape[0], chain.M
        # window-major (M, ., P): every step below is a batched small matmul over the windows
        zc = np.zeros((M, chain.q, P))
        zc[chain.pos, chain.slot] = z.T
        rhs = np.matmul(self.gains, zc)  # K_m z_m, (M, n, P)
        x, info = dtbtrs(self._band, rhs.reshape(M * n, P), uplo="L", diag="U")
        if info != 0:  # a unit triangular band has no singular pivot
            raise RuntimeError(f"wander whitening: tbtrs info {info}")
        x = x.reshape(M, n, P)
        pred = np.empty_like(x)  # Phi_m x_{m-1}: the state predicted at window m
        pred[0] = 0.0
        pred[1:] = x[:-1] * self.phi[1:, :, None]
        w = np.matmul(self.linv, zc - np.matmul(self.H, pred))
        return w[chain.pos, chain.slot].T


class WanderCovariance:
    """The covariance a wander model adds to a problem's window residuals, in state-space form:
    the model, the residuals' :class:`WanderSensitivity` (at the estimate it was built at), the
    windows' mid-times and sessions. :meth:`whitening` builds the :class:`Whitening` for the
    residuals' current 1-sigma and keeps it (problems copied with other fields share it);
    :meth:`dense` is the (R, R) matrix, for small problems and tests."""

    def __init__(
        self,
        model: WanderModel,
        sensitivity: WanderSensitivity,
        t: np.ndarray | None,
        sessions: np.ndarray | None = None,
    ) -> None:
        self.model, self.sensitivity, self.t, self.sessions = model, sensitivity, t, sessions
        self._last: tuple[np.ndarray, Whitening] | None = None

    def whitening(self, sigma: np.ndarray) -> Whitening:
        sigma = np.asarray(sigma, float)
        if self._last is None or not np.array_equal(self._last[0], sigma):
            W = Whitening(sigma, self.sensitivity, self.t, self.model, self.sessions)
            self._last = (sigma.copy(), W)
        return self._last[1]

    def dense(self) -> np.ndarray:
        return wander_covariance(self.sensitivity, self.t, self.model, self.sessions)


# ---- dense references (small problems and tests) --------------------------------------------
def correlation(t: np.ndarray, tau_s: float) -> np.ndarray:
    """(M, M) exp(-|t_i - t_j| / tau); tau 0: the identity, inf: all ones (dense: tests)."""
    if tau_s == 0.0:
        return np.eye(len(t))
    if math.isinf(tau_s):
        return np.ones((len(t), len(t)))
    return np.exp(-np.abs(t[:, None] - t[None, :]) / tau_s)


def wander_covariance(
    sensitivity: Any,
    t: np.ndarray | None,
    model: WanderModel,
    sessions: np.ndarray | None = None,
) -> np.ndarray:
    """(R, R) covariance the wander adds to the window residuals, dense: R^2 memory, the
    reference :class:`Whitening` and :func:`estimate_wander` are checked against on small
    problems (the calibration never builds it).

    ``sensitivity``: a :class:`WanderSensitivity` or sensor -> (R, M, 3); ``t``: (M,) mid-times,
    s, or None (independent windows); ``sessions``: (M,) session of each window (None: one),
    windows of different sessions independent."""
    sens = as_sensitivity(sensitivity)
    R, M = sens.n_residuals, sens.n_windows
    out = np.zeros((R, R))
    same = np.ones((M, M)) if sessions is None else sessions[:, None] == sessions[None, :]
    for s, g in sens.rows.items():
        tw = model.triads.get(s)
        if tw is None:
            continue
        for a in range(3):  # 3 axes; each term is one (R, R) outer product through the windows
            if tw.sigma[a] == 0:
                continue
            rho = correlation(t, float(tw.tau_s[a])) if t is not None else np.eye(M)
            rho = (rho * same)[np.ix_(sens.window, sens.window)]
            out += tw.sigma[a] ** 2 * (g[:, a, None] * rho * g[None, :, a])
    return out


def whitener(sigma: np.ndarray, cov_wander: np.ndarray) -> np.ndarray:
    """W (R, R) such that W r_std has unit covariance, r_std = r / sigma: the inverse Cholesky
    factor of I + diag(1/sigma) Sigma_w diag(1/sigma) (dense: tests and small problems)."""
    C = np.eye(len(sigma)) + cov_wander / np.outer(sigma, sigma)
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(C)
        C = (V * np.maximum(w, _JITTER)) @ V.T
        L = np.linalg.cholesky(C)
    return np.linalg.solve(L, np.eye(len(sigma)))


def innovations(
    residual: np.ndarray,
    signature: np.ndarray,
    noise_cov: np.ndarray,
    H: Mapping[str, np.ndarray],
    t: np.ndarray | None,
    sessions: np.ndarray | None,
    model: WanderModel,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The window residuals as a Kalman filter's innovations under the wander, for tests that
    take windows in order and need them independent (the drift test's GLR).

    residual (M, K), signature (M, K, D) (d residual / d a coefficient change), noise_cov
    (M, K, K) the windows' own noise; H: sensor -> (M, K, 3) d residual / d that triad's output
    per axis; the wander state (one per axis of each triad in ``model``) follows its
    Gauss-Markov law between windows (restarted at each session). Returns the innovations
    nu_k = r_k - H x_k|k-1, the signatures run through the same filter (a change present from
    the first window; a step later in the window sequence is approximated by it) and the
    innovations' covariance S_k = H P H^T + R_k. Independent when the model is right."""
    M, K = residual.shape
    names = [s for s in ("gyro", "accel") if s in model.triads and s in H]
    if not names:
        return residual, signature, noise_cov
    sig = np.concatenate([model.triads[s].sigma for s in names])
    tau = np.concatenate([model.triads[s].tau_s for s in names])
    Hall = np.concatenate([H[s] for s in names], axis=2)  # (M, K, n)
    n = len(sig)
    D = signature.shape[2]
    nu, A2, S2 = residual.copy(), signature.copy(), noise_cov.copy()
    x, XA, P = np.zeros(n), np.zeros((n, D)), np.diag(sig**2)
    for k in range(M):  # a filter over windows: each step is a few small matrix products
        first = k == 0 or (sessions is not None and sessions[k] != sessions[k - 1])
        if first:
            x, XA, P = np.zeros(n), np.zeros((n, D)), np.diag(sig**2)
        else:
            gap = 0.0 if t is None else max(float(t[k] - t[k - 1]), 0.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                phi = np.where(tau > 0, np.exp(-gap / np.where(tau > 0, tau, 1.0)), 0.0)
            if t is None:
                phi = np.zeros(n)
            x, XA = phi * x, phi[:, None] * XA
            P = phi[:, None] * P * phi[None, :] + np.diag(sig**2 * (1.0 - phi**2))
        Hk = Hall[k]
        Sk = Hk @ P @ Hk.T + noise_cov[k]
        Sk = 0.5 * (Sk + Sk.T)
        nu[k] = residual[k] - Hk @ x
        A2[k] = signature[k] - Hk @ XA
        S2[k] = Sk
        gain = np.linalg.solve(Sk, Hk @ P).T  # P H^T S^-1, (n, K)
        x = x + gain @ nu[k]
        XA = XA + gain @ A2[k]
        P = P - gain @ Hk @ P
        P = 0.5 * (P + P.T)
    return nu, A2, S2
