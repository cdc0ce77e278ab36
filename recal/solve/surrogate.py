"""The swarms' objective with the motion invariants linearised about a reference solution.

The slew invariant (and the known rotations and closed turns, which integrate the same
increments) costs ~0.2 ms per parameter vector: every evaluation composes 64 group rotations per
slew. The static invariants (norms, dot product) cost a few microseconds. An MCS-NAFSA evaluates
millions of parameter vectors, so with slews almost all of its time went into re-integrating
rotations that barely change between neighbouring fish.

:class:`SurrogateProblem` keeps the static invariants exact and replaces the motion residuals
r(theta) by their first-order expansion about a reference ``theta_ref``::

    r(theta) ~ r(theta_ref) + J (theta - theta_ref),   J = d r / d theta at theta_ref

(J by central differences: 2 D exact evaluations in one batched call). The motion part of the
swarm objective is then a quadratic form in the phase coordinates, so a swarm evaluation costs
a d x d product whatever the number of slews. :mod:`recal.solve.mcs` refreshes the reference at the
runs' mean at the start of every cycle, so the expansion is taken where the fish are; the
reported answer is checked against the exact objective afterwards (:mod:`recal.solve.convergence`).
The slew residuals are close to linear over the region a cycle searches (a few sigma: micro- to
milliradians of frame error), so the surrogate's minimiser matches the exact one to a small
fraction of a sigma once the reference is within a few sigma of it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from recal.solve.problem import Problem
from recal.solve.problem_objective import LINEAR_INVARIANTS

#: Invariants that integrate the gyro over the slews (expensive, linearised here).
MOTION_INVARIANTS = ("slew", "rotation", "closure")
#: Finite-difference step of the Jacobian, in units of each parameter's typical change.
JACOBIAN_STEP = 1e-3


def motion_names(problem: Problem) -> tuple[str, ...]:
    """The problem's motion invariants (empty without slews)."""
    return tuple(n for n in problem.invariant_names if n in MOTION_INVARIANTS)


def _motion_weights(problem: Problem, names: tuple[str, ...]) -> np.ndarray:
    """sqrt of each motion residual's weight in :meth:`Problem.objective`: 1 / (sigma sqrt(R - 1))
    for the least squares; with ``paper_objective``, (indicator / floor)^2 = sum r^2 / ((n - 1)
    floor^2) for a linear invariant."""
    if not problem.paper_objective:
        dof = max(problem.n_residuals - 1, 1)
        parts = [1.0 / (np.sqrt(dof) * np.broadcast_to(problem.sigma[n], (problem.n_of(n),)))
                 for n in names]  # fmt: skip
        return np.concatenate(parts) if parts else np.zeros(0)
    floor = problem.indicator_floor()
    parts = [
        np.full(problem.n_of(n), 1.0 / (np.sqrt(max(problem.n_of(n) - 1, 1)) * floor[n]))
        for n in names
    ]
    return np.concatenate(parts) if parts else np.zeros(0)


def _weighted_motion(problem: Problem, names: tuple[str, ...], theta: np.ndarray) -> np.ndarray:
    """Weighted motion residuals (P, n): their squared sum is the motion part of the objective."""
    if not names:
        return np.zeros((np.atleast_2d(theta).shape[0], 0))
    raw = problem.raw_residuals(theta)
    return np.concatenate([raw[n] for n in names], axis=1) * _motion_weights(problem, names)


def data_noise(problem: Problem, runs: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Per Monte Carlo run, the measurement noise each invariant's data is perturbed by.

    Invariant name -> (runs, n) offsets to the residual in the form eq. (14) squares (|x|^2 -
    ref^2 for a norm: 2 ref sigma eps; the linear ones: sigma eps), eps ~ N(0, 1) independent
    per residual, as the Gauss-Newton covariance assumes. Runs come in antithetic pairs (eps,
    -eps), so the mean over the runs is free of the perturbation to first order while each run
    scatters as an independent data set would."""
    names = problem.invariant_names
    n = sum(problem.n_of(k) for k in names)
    half = rng.standard_normal(((runs + 1) // 2, n))
    eps = np.empty((runs, n))
    eps[0::2] = half
    eps[1::2] = -half[: runs // 2]
    out, at = {}, 0
    for k in names:
        m = problem.n_of(k)
        scale = 1.0 if k in LINEAR_INVARIANTS else 2.0 * problem.reference(k)
        out[k] = scale * problem.sigma[k] * eps[:, at : at + m]
        at += m
    return out


@dataclass(frozen=True)
class SurrogateProblem:
    """Static invariants exact, motion invariants linear about ``theta_ref``; optionally each
    Monte Carlo run's data perturbed by its noise (:func:`data_noise`).

    exact: the full problem. static: the same problem without the motion invariants.
    e0: (n,) weighted motion residuals at ``theta_ref``; J: (n, D) their Jacobian (n = 0
    without slews). noise: invariant -> (R, n) per-run offsets, or None.
    """

    exact: Problem
    static: Problem
    theta_ref: np.ndarray
    e0: np.ndarray
    J: np.ndarray
    noise: dict[str, np.ndarray] | None = None

    @classmethod
    def at(
        cls,
        problem: Problem,
        theta_ref: np.ndarray,
        typical: np.ndarray,
        noise: dict[str, np.ndarray] | None = None,
    ) -> SurrogateProblem:
        """Linearise ``problem``'s motion invariants about ``theta_ref`` (2 D + 1 exact
        evaluations in one batch; ``typical`` (D,) sets the finite-difference steps)."""
        names = motion_names(problem)
        static = replace(problem, slews=None, known_rotations=None, closed_turns=None)
        theta_ref = np.asarray(theta_ref, float)
        D = theta_ref.shape[0]
        if names:
            step = JACOBIAN_STEP * np.asarray(typical, float)
            pts = np.concatenate([theta_ref[None], theta_ref + np.diag(step),
                                  theta_ref - np.diag(step)])  # fmt: skip
            e = _weighted_motion(problem, names, pts)
            J = (e[1 : D + 1] - e[D + 1 :]).T / (2.0 * step)
            e0 = e[0]
        else:
            e0, J = np.zeros(0), np.zeros((0, D))
        return cls(problem, static, theta_ref, e0, J, noise)

    @property
    def evaluations(self) -> int:
        """Exact evaluations spent on the expansion."""
        return 2 * self.theta_ref.shape[0] + 1 if self.J.shape[0] else 0

    def _motion_noise(self, run: np.ndarray | None) -> np.ndarray | float:
        if self.noise is None or run is None or not self.J.shape[0]:
            return 0.0
        names = motion_names(self.exact)
        w = _motion_weights(self.exact, names)
        return np.concatenate([self.noise[n][run] for n in names], axis=1) * w

    def motion_residuals(self, theta: np.ndarray, run: np.ndarray | None = None) -> np.ndarray:
        """Linearised weighted motion residuals (P, n), run ``run``'s noise added."""
        e = self.e0 + (np.atleast_2d(theta) - self.theta_ref) @ self.J.T
        return e + self._motion_noise(run)

    def _static_objective(self, theta: np.ndarray, run: np.ndarray | None) -> np.ndarray:
        """The static invariants' part of :meth:`Problem.objective`, run ``run``'s noise added
        (the least squares: over the exact problem's R - 1, not the static one's)."""
        f = self._perturbed(self.static, theta, run)
        if self.static.paper_objective:
            return f
        return f * (self.static.objective_dof / self.exact.objective_dof)

    def objective(self, theta: np.ndarray, run: np.ndarray | None = None) -> np.ndarray:
        """:meth:`Problem.objective` with the motion part linearised, (P,); ``run`` (P,): the
        Monte Carlo run of each row, whose perturbed data it is evaluated on."""
        e = self.motion_residuals(theta, run)
        return self._static_objective(theta, run) + np.einsum("pn,pn->p", e, e)

    def exact_objective(self, theta: np.ndarray, run: np.ndarray | None = None) -> np.ndarray:
        """The exact objective (motion invariants integrated), each run on its perturbed data."""
        return self._perturbed(self.exact, theta, run)

    def _perturbed(self, problem: Problem, theta: np.ndarray, run: np.ndarray | None) -> np.ndarray:
        """``problem``'s objective on run ``run``'s perturbed data (:meth:`Problem.objective`)."""
        if self.noise is None or run is None:
            return problem.objective(theta)
        names = problem.invariant_names
        return problem.objective(theta, {n: self.noise[n][run] for n in names})

    def phase_objective(
        self, base: np.ndarray, transform: np.ndarray
    ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """f(X, run) = objective(base[run] + X transform^T, run) for phase coordinates X (P, d).

        The motion part is the quadratic form c_r + 2 g_r.x + x^T H x (per run r), so its cost
        does not grow with the number of slews."""
        runs = np.arange(base.shape[0])
        Jt = self.J @ transform  # (n, d)
        e_run = self.motion_residuals(base, runs)  # (R, n)
        c = np.einsum("rn,rn->r", e_run, e_run)
        g = e_run @ Jt  # (R, d)
        H = Jt.T @ Jt  # (d, d)

        def f(X: np.ndarray, run: np.ndarray) -> np.ndarray:
            quad = c[run] + np.einsum("pd,pd->p", X, 2.0 * g[run] + X @ H)
            return self._static_objective(base[run] + X @ transform.T, run) + quad

        return f
