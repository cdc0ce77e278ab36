"""Levenberg-Marquardt on the observable directions, and the Gauss-Newton covariance."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from recal.observability import jacobian
from recal.problem import Problem


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

    With window noise known (std columns), the covariance is scaled by max(1, chi2_red) so that
    an unmodelled effect widens it instead of being hidden; with noise estimated from the
    residuals chi2_red is ~1 by construction.
    """
    J = jacobian(problem, theta, transform.T)
    r = problem.residuals(theta[None])[0]
    dof = max(problem.n_residuals - transform.shape[1], 1)
    chi2_red = float(r @ r / dof)
    cov_z = np.linalg.pinv(J.T @ J)
    scale = max(1.0, chi2_red) if problem.noise_known else chi2_red
    return transform @ cov_z @ transform.T * scale, chi2_red
