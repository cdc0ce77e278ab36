"""The swarms' objective as a Gauss-Newton model about a reference solution.

An MCS-NAFSA evaluates millions of parameter vectors. Evaluated exactly, the slew invariant (and
the known rotations and closed turns, which integrate the same increments) costs ~0.2 ms per
vector -- every evaluation composes 64 group rotations per slew -- and the static invariants a
few microseconds (the accelerometer's inverse model, the norms). Almost all of a swarm's time
went into re-evaluating residuals that barely change between neighbouring fish.

:class:`SurrogateProblem` replaces the whitened residuals r(theta) of the least squares by their
first-order expansion about a reference ``theta_ref``::

    r(theta) ~ r(theta_ref) + J (theta - theta_ref),   J = d r / d theta at theta_ref

(J by central differences: 2 D + 1 exact evaluations in one batched call). The swarm objective,
|r + eps_run|^2 / (R - 1), is then a quadratic form in the phase coordinates, c_r + 2 g_r.x +
x^T H x per Monte Carlo run, so an evaluation costs a d x d product whatever the number of
windows and slews. :mod:`recal.solve.mcs` refreshes the reference at the runs' mean at the start
of every cycle (a Gauss-Newton iteration whose step the swarm searches for), the exact
objective decides when the cycles stall, and the reported answer is checked against the exact
objective's minimum afterwards (:mod:`recal.solve.convergence`). The residuals are close to
linear over the region a cycle searches once the reference is within a few sigma of the minimum
(micro- to milliradians of frame error, a norm's curvature ~ sigma^2 / reference), so the
model's minimiser matches the exact one to a small fraction of a sigma.

``linear="motion"`` keeps the static invariants exact and linearises the motion ones only (the
form before 0.2.0; also what the seed's eq. (14) objective, ``--paper``, allows, since it is not a
sum of squared residuals).
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


#: What :meth:`SurrogateProblem.at` linearises: every residual (Gauss-Newton, the least squares
#: only) or the motion invariants only (the static ones exact).
LINEAR_SCOPES = ("all", "motion")


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


def _every_residual(problem: Problem, names: tuple[str, ...]) -> bool:
    """``names`` are all the least squares' invariants: their weighting is the whitening of
    :meth:`Problem.residuals` (the bias wander's included), over sqrt(R - 1)."""
    return names == problem.invariant_names and not problem.paper_objective


def _weighted(problem: Problem, names: tuple[str, ...], theta: np.ndarray) -> np.ndarray:
    """Weighted residuals (P, n) of invariants ``names``: their squared sum is those invariants'
    part of the objective (all invariants: the whitened residuals over sqrt(R - 1), the bias
    wander's whitening included)."""
    P = np.atleast_2d(theta).shape[0]
    if not names:
        return np.zeros((P, 0))
    if _every_residual(problem, names):
        return problem.residuals(theta) / np.sqrt(problem.objective_dof)
    raw = problem.raw_residuals(theta)
    return np.concatenate([raw[n] for n in names], axis=1) * _motion_weights(problem, names)


def _weighted_noise(problem: Problem, names: tuple[str, ...], noise, run) -> np.ndarray | float:
    """The per-run data noise in the weighting of :func:`_weighted`, rows ``run``."""
    if noise is None or run is None or not names:
        return 0.0
    if _every_residual(problem, names):
        eps = problem.whitened_offsets({n: noise[n][run] for n in names})
        return eps / np.sqrt(problem.objective_dof)
    w = _motion_weights(problem, names)
    return np.concatenate([noise[n][run] for n in names], axis=1) * w


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
    """The linearised invariants' residuals about ``theta_ref`` and the others exact; optionally
    each Monte Carlo run's data perturbed by its noise (:func:`data_noise`).

    exact: the full problem. linear: the invariants linearised (all of them, or the motion
    ones). kept: the problem of the invariants evaluated exactly (None when every one is
    linear). e0: (n,) weighted residuals of the linear invariants at ``theta_ref``; J: (n, D)
    their Jacobian (n = 0 when none). noise: invariant -> (R, n) per-run offsets, or None.
    """

    exact: Problem
    linear: tuple[str, ...]
    kept: Problem | None
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
        scope: str = "all",
    ) -> SurrogateProblem:
        """Linearise ``problem``'s residuals about ``theta_ref`` (2 D + 1 exact evaluations in
        one batch; ``typical`` (D,) sets the finite-difference steps). ``scope``: "all" (the
        least squares; the seed's eq. (14) objective falls back to "motion") or "motion"."""
        if scope not in LINEAR_SCOPES:
            raise ValueError(f"scope must be one of {LINEAR_SCOPES}, got {scope!r}")
        if scope == "all" and not problem.paper_objective:
            names, kept = problem.invariant_names, None
        else:
            names = motion_names(problem)
            kept = replace(problem, slews=None, known_rotations=None, closed_turns=None)
        theta_ref = np.asarray(theta_ref, float)
        D = theta_ref.shape[0]
        if names:
            step = JACOBIAN_STEP * np.asarray(typical, float)
            pts = np.concatenate([theta_ref[None], theta_ref + np.diag(step),
                                  theta_ref - np.diag(step)])  # fmt: skip
            e = _weighted(problem, names, pts)
            J = (e[1 : D + 1] - e[D + 1 :]).T / (2.0 * step)
            e0 = e[0]
        else:
            e0, J = np.zeros(0), np.zeros((0, D))
        return cls(problem, names, kept, theta_ref, e0, J, noise)

    @property
    def evaluations(self) -> int:
        """Exact evaluations spent on the expansion."""
        return 2 * self.theta_ref.shape[0] + 1 if self.J.shape[0] else 0

    def linear_residuals(self, theta: np.ndarray, run: np.ndarray | None = None) -> np.ndarray:
        """Linearised weighted residuals (P, n), run ``run``'s noise added."""
        e = self.e0 + (np.atleast_2d(theta) - self.theta_ref) @ self.J.T
        return e + _weighted_noise(self.exact, self.linear, self.noise, run)

    def _kept_objective(self, theta: np.ndarray, run: np.ndarray | None) -> np.ndarray | float:
        """The exact invariants' part of :meth:`Problem.objective`, run ``run``'s noise added
        (the least squares: over the full problem's R - 1, not the kept one's)."""
        if self.kept is None:
            return 0.0
        f = self._perturbed(self.kept, theta, run)
        if self.kept.paper_objective:
            return f
        return f * (self.kept.objective_dof / self.exact.objective_dof)

    def objective(self, theta: np.ndarray, run: np.ndarray | None = None) -> np.ndarray:
        """:meth:`Problem.objective` with the linear invariants linearised, (P,); ``run`` (P,):
        the Monte Carlo run of each row, whose perturbed data it is evaluated on."""
        e = self.linear_residuals(theta, run)
        return self._kept_objective(theta, run) + np.einsum("pn,pn->p", e, e)

    def exact_objective(self, theta: np.ndarray, run: np.ndarray | None = None) -> np.ndarray:
        """The exact objective (motion invariants integrated), each run on its perturbed data."""
        return self._perturbed(self.exact, theta, run)

    def exact_objectives(
        self, theta: np.ndarray, run: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The exact objective at ``theta`` on each row's perturbed data and on the data as
        measured, from one evaluation of the residuals (the least squares; ``theta`` (1, D)
        broadcasts against ``run``)."""
        problem = self.exact
        if self.noise is None or run is None:
            f = problem.objective(theta)
            return f, f
        if problem.paper_objective:
            return self._perturbed(problem, theta, run), problem.objective(theta)
        r = problem.residuals(theta)
        eps = problem.whitened_offsets({n: self.noise[n][run] for n in problem.invariant_names})
        return problem.least_squares(r + eps), problem.least_squares(r)

    def _perturbed(self, problem: Problem, theta: np.ndarray, run: np.ndarray | None) -> np.ndarray:
        """``problem``'s objective on run ``run``'s perturbed data (:meth:`Problem.objective`)."""
        if self.noise is None or run is None:
            return problem.objective(theta)
        names = problem.invariant_names
        return problem.objective(theta, {n: self.noise[n][run] for n in names})

    @property
    def quadratic(self) -> bool:
        """Every residual linearised: the objective is a quadratic form in the parameters."""
        return self.kept is None

    def jacobian_along(self, directions: np.ndarray) -> np.ndarray:
        """The whitened residuals' Jacobian along ``directions`` (k, D) at ``theta_ref``, (R, k),
        as :func:`recal.solve.observability.jacobian` gives it, from the model's own J (every
        residual linear only)."""
        if not self.quadratic:
            raise ValueError("only a model of every residual has their Jacobian")
        return np.sqrt(self.exact.objective_dof) * (self.J @ directions.T)

    def phase_quadratic(
        self, base: np.ndarray, transform: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The linear part of the objective at base[r] + transform x, per run r, as
        c_r + g_r.x + x^T H x: (c (R,), g (R, d), H (d, d))."""
        runs = np.arange(base.shape[0])
        Jt = self.J @ transform  # (n, d)
        e_run = self.linear_residuals(base, runs)  # (R, n)
        return np.einsum("rn,rn->r", e_run, e_run), 2.0 * (e_run @ Jt), Jt.T @ Jt

    def phase_objective(
        self, base: np.ndarray, transform: np.ndarray
    ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """f(X, run) = objective(base[run] + X transform^T, run) for phase coordinates X (P, d).

        The linear part is the quadratic form :meth:`phase_quadratic`, so its cost does not grow
        with the number of windows or slews."""
        c, g, H = self.phase_quadratic(base, transform)
        if self.kept is None:

            def quadratic(X: np.ndarray, run: np.ndarray) -> np.ndarray:
                return c[run] + np.einsum("pd,pd->p", X, g[run] + X @ H)

            return quadratic

        def f(X: np.ndarray, run: np.ndarray) -> np.ndarray:
            quad = c[run] + np.einsum("pd,pd->p", X, g[run] + X @ H)
            return self._kept_objective(base[run] + X @ transform.T, run) + quad

        return f
