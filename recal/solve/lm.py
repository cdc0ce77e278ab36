"""Levenberg-Marquardt on the observable directions, and the Gauss-Newton covariance."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from recal.solve.observability import jacobian
from recal.solve.problem import Problem


@dataclass(frozen=True)
class LMResult:
    theta: np.ndarray  # (D,)
    cost: float  # 0.5 * sum of squared whitened residuals
    evaluations: int  # residual vectors evaluated (Jacobian columns included)
    success: bool
    message: str


def to_theta(theta_ref: np.ndarray, transform: np.ndarray, z: np.ndarray) -> np.ndarray:
    """theta = theta_ref + transform @ z, batched over z of shape (P, k)."""
    return theta_ref + np.atleast_2d(z) @ transform.T


def solve_lm(
    problem: Problem, theta_ref: np.ndarray, transform: np.ndarray, max_nfev: int = 200
) -> LMResult:
    """Minimise the whitened residuals over theta = theta_ref + transform @ z.

    ``transform`` (D, k) is typical * basis: the observable directions in parameter units; the
    directions not in it stay at ``theta_ref`` (the prior).
    """
    k = transform.shape[1]
    count = [0]

    def fun(z: np.ndarray) -> np.ndarray:
        count[0] += 1
        return problem.residuals(to_theta(theta_ref, transform, z))[0]

    def jac(z: np.ndarray) -> np.ndarray:
        count[0] += 2 * k
        return jacobian(problem, to_theta(theta_ref, transform, z)[0], transform.T)

    method = "lm" if problem.n_residuals >= k else "trf"
    res = least_squares(
        fun,
        np.zeros(k),
        jac=jac,
        method=method,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=max_nfev,
    )
    theta = to_theta(theta_ref, transform, res.x)[0]
    return LMResult(theta, float(res.cost), count[0], bool(res.success), str(res.message))


def covariance(
    problem: Problem, theta: np.ndarray, transform: np.ndarray
) -> tuple[np.ndarray, float]:
    """Gauss-Newton covariance of theta (D, D) and the reduced chi-square at ``theta``.

    With window noise known (std or sem columns), the covariance is scaled by max(1, chi2_red) so that
    an unmodelled effect widens it instead of being hidden; with noise estimated from the
    residuals chi2_red is ~1 by construction. Without redundancy (as many observable directions
    as equations) chi2_red is NaN, and so is the covariance unless the noise is known.
    """
    J = jacobian(problem, theta, transform.T)  # (R, k): memory linear in the positions
    r = problem.residuals(theta[None])[0]
    dof = problem.n_residuals - transform.shape[1]
    # exactly determined (dof 0): every residual is fitted away, so chi2 says nothing
    chi2_red = float(r @ r / dof) if dof > 0 else float("nan")
    # pinv of the k x k normal matrix through the economy SVD of J: (V S^-2 V^T)
    _, s, Vt = np.linalg.svd(J, full_matrices=False)
    inv = np.where(s > 1e-12 * s.max(), 1.0 / np.maximum(s, 1e-300) ** 2, 0.0) if s.size else s
    cov_z = (Vt.T * inv) @ Vt
    if problem.noise_known:
        scale = max(1.0, chi2_red) if dof > 0 else 1.0
    else:  # noise from the residuals: unknown without redundancy
        scale = chi2_red
    return transform @ cov_z @ transform.T * scale, chi2_red
