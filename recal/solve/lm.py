"""Levenberg-Marquardt on the observable directions, and the Gauss-Newton covariance."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from recal.solve.observability import FD_STEP, jacobian
from recal.solve.problem import Problem


@dataclass(frozen=True)
class LMResult:
    theta: np.ndarray  # (D,)
    cost: float  # 0.5 * sum of squared whitened residuals
    evaluations: int  # residual vectors evaluated (Jacobian columns included)
    success: bool
    message: str
    #: with motion invariants, the last linearisation: (theta there, whitened Jacobian (R, k)
    #: along the transform); pass it to the next solve_lm on the same problem and directions
    linearisation: tuple[np.ndarray, np.ndarray] | None = None


def to_theta(theta_ref: np.ndarray, transform: np.ndarray, z: np.ndarray) -> np.ndarray:
    """theta = theta_ref + transform @ z, batched over z of shape (P, k)."""
    return theta_ref + np.atleast_2d(z) @ transform.T


#: Motion invariants (recal.solve.surrogate.MOTION_INVARIANTS): they integrate the gyro over
#: every slew, so one residual vector costs milliseconds per thousand slews where the static
#: invariants cost microseconds.
_MOTION = ("slew", "rotation", "closure")
#: With motion invariants, LM runs on their Jacobian frozen at a linearisation point and
#: re-linearises until the estimate moves by less than this (sigma: the norm of the whitened
#: residual change) from that point.
RELINEARISE_SIGMA = 0.05
#: Linearisation points at most (each costs k + 1 exact evaluations; 1-3 usually do).
MAX_LINEARISATIONS = 8


def solve_lm(
    problem: Problem,
    theta_ref: np.ndarray,
    transform: np.ndarray,
    max_nfev: int = 200,
    linearisation: tuple[np.ndarray, np.ndarray] | None = None,
) -> LMResult:
    """Minimise the whitened residuals over theta = theta_ref + transform @ z.

    ``transform`` (D, k) is typical * basis: the observable directions in parameter units; the
    directions not in it stay at ``theta_ref`` (the prior).

    With motion invariants (slews) the residuals stay exact but their Jacobian is taken once per
    linearisation point (a chord method) while the static invariants' is taken at every step:
    LM is re-run from its answer with the motion Jacobian taken there until the answer moves by
    less than :data:`RELINEARISE_SIGMA`. The minimum is the exact one (the last Jacobian is the
    one at it), at a fraction of the integrations: thousands of slews stay fast.
    ``linearisation``: a previous :attr:`LMResult.linearisation` on this problem and these
    directions, used for the first round (a restart from the prior near a settled answer then
    needs no new one).
    """
    k = transform.shape[1]
    count = [0]

    def fun(z: np.ndarray) -> np.ndarray:
        count[0] += 1
        return problem.residuals(to_theta(theta_ref, transform, z))[0]

    motion = [n for n in problem.invariant_names if n in _MOTION]
    method = "lm" if problem.n_residuals >= k else "trf"
    options = {"method": method, "xtol": 1e-12, "ftol": 1e-12, "gtol": 1e-12}
    if not motion or not k:

        def jac(z: np.ndarray) -> np.ndarray:
            count[0] += 2 * k
            return jacobian(problem, to_theta(theta_ref, transform, z)[0], transform.T)

        res = least_squares(fun, np.zeros(k), jac=jac, max_nfev=max_nfev, **options)
        theta = to_theta(theta_ref, transform, res.x)[0]
        return LMResult(theta, float(res.cost), count[0], bool(res.success), str(res.message))
    static = replace(problem, slews=None, known_rotations=None, closed_turns=None)
    n_static = static.n_residuals  # the motion invariants come last (Problem.invariant_names)
    z = np.zeros(k)
    res = None
    given = None
    if linearisation is not None and linearisation[1].shape == (problem.n_residuals, k):
        at, J_given = linearisation
        z_at = np.linalg.lstsq(transform, at - theta_ref, rcond=None)[0]
        if np.allclose(to_theta(theta_ref, transform, z_at)[0], at, rtol=1e-12, atol=0):
            given = (z_at, J_given)  # (it lies on these directions)
    for _ in range(MAX_LINEARISATIONS):
        if given is not None:
            (z_at, J_at), given = given, None
        else:
            z_at = z
            J_at = _forward_jacobian(problem, to_theta(theta_ref, transform, z)[0], transform.T)
            count[0] += k + 1
        J_motion = J_at[n_static:]

        def jac(zz: np.ndarray, J_motion=J_motion) -> np.ndarray:
            count[0] += 2 * k  # static invariants only: cheap
            J_static = jacobian(static, to_theta(theta_ref, transform, zz)[0], transform.T)
            return np.vstack([J_static, J_motion])

        res = least_squares(fun, z, jac=jac, max_nfev=max_nfev, **options)
        moved = float(np.linalg.norm(J_at @ (res.x - z_at)))
        z = res.x
        if moved < RELINEARISE_SIGMA:
            break
    assert res is not None
    theta = to_theta(theta_ref, transform, z)[0]
    last = (to_theta(theta_ref, transform, z_at)[0], J_at)
    return LMResult(theta, float(res.cost), count[0], bool(res.success), str(res.message), last)


def _forward_jacobian(problem: Problem, theta: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Whitened residual Jacobian (R, k) by forward differences (k + 1 points in one batch):
    half the integrations of central ones, and the chord method only needs a guide (its
    residuals are exact, and it re-linearises at its answer)."""
    pts = np.concatenate([theta[None], theta + FD_STEP * directions])
    r = problem.residuals(pts)
    return (r[1:] - r[:1]).T / FD_STEP


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
