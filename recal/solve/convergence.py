"""A calibration that does not depend on where it started: iterate the fit to a fixed point.

One Levenberg-Marquardt run minimises the whitened residuals of a problem whose noise was
propagated through the *prior* and whose observable directions were judged at the prior. Both
change with the estimate: calibrating again with the output as the prior builds another
problem and lands elsewhere (imucal's Ferraris session: chi2_red 110, then 72, then 61). So
:func:`fixed_point` repeats

    problem at theta (noise and slew basis at the estimate) -> LM from theta on the same
    observable directions (held directions stay at the prior)

for :data:`REREFERENCE` rounds, then LM on the problem kept fixed, until a round moves the
estimate by less than :data:`SETTLED_SIGMA` in Mahalanobis norm (the change of the whitened
residuals, ||r(new) - r(old)||, over sqrt(max(1, chi2_red)): in units of the reported 1-sigma).
It then restarts once from the prior on the settled problem: when the two answers agree the
calibration is start-independent, else ``converged`` is false with the reason (a local
minimum: the lower one is kept).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from recal.solve.lm import covariance, solve_lm
from recal.solve.observability import analyze
from recal.solve.problem import Problem

#: A round that moves the estimate by less than this (Mahalanobis norm, sigma) has settled.
SETTLED_SIGMA = 0.05
#: Rounds before giving up: each is one LM run, usually 1-3 are needed.
MAX_ROUNDS = 8
#: Rounds that re-reference the noise at the estimate before the problem is kept fixed.
REREFERENCE = 2
#: Re-referencing that changes an invariant's RMS noise by more than this factor is refused.
MAX_SIGMA_RATIO = 2.0
#: Two answers closer than this are the same answer: Mahalanobis norm in sigma for LM's restart
#: from the prior (deterministic: another minimum is far away), and per observable direction
#: (the norm over sqrt(k)) for a swarm, whose Monte Carlo mean sits a fraction of a sigma from
#: the minimum in every direction (1.2 sigma over 24 directions is 0.25 sigma each: well inside
#: the estimate's own uncertainty).
SAME_ANSWER_SIGMA = 0.5


class FixedPoint(NamedTuple):
    problem: Problem
    theta: np.ndarray
    evaluations: int
    convergence: dict[str, Any]  # {"converged", "reason", "rounds", ...} (calibrate's JSON)


def projected_start(theta: np.ndarray, theta0: np.ndarray, typical: np.ndarray, basis):
    """theta with its displacement from the prior kept on the observable directions only."""
    d = (theta - theta0) / typical
    return theta0 + typical * (basis @ (basis.T @ d))


def _distance(problem: Problem, a: np.ndarray, b: np.ndarray) -> float:
    """Mahalanobis distance of two estimates, to first order: ||r(a) - r(b)|| (sigma)."""
    r = problem.residuals(np.stack([a, b]))
    return float(np.linalg.norm(r[0] - r[1]))


def _cost(problem: Problem, theta: np.ndarray) -> float:
    r = problem.residuals(theta[None])[0]
    return float(0.5 * r @ r)


def _settle(problem, theta, theta0, typical, basis, rereference: int = REREFERENCE):
    """LM rounds until a round moves the estimate by < SETTLED_SIGMA; the first ``rereference``
    rounds re-reference the noise at the estimate, later ones keep the problem fixed (and reuse
    the slews' last linearisation, also returned).

    The observable directions stay those of the first solve (``basis``): judged again at every
    estimate they can flip between rounds, and a flipped direction would lose its estimate.
    Re-referencing is bounded because on a misfit recording (slews with unmodelled motion) the
    propagated noise follows the estimate and the rounds need not settle."""
    evaluations, rounds, moved = 0, 0, np.inf
    T = typical[:, None] * basis
    linearisation = None  # the slews' last Jacobian, while the problem stays the same
    while rounds < MAX_ROUNDS and T.shape[1]:
        if problem.noise_known and rounds < rereference:
            moved_to = problem.at(theta)
            if _comparable(problem, moved_to):
                problem, linearisation = moved_to, None
            else:  # a degenerate estimate (scale running away): keep the noise where it was
                rereference = rounds
        rounds += 1
        lm = solve_lm(problem, theta, T, linearisation=linearisation)
        linearisation = lm.linearisation
        evaluations += lm.evaluations
        moved = _distance(problem, lm.theta, theta) / np.sqrt(max(1.0, _chi2(problem, lm.theta, T)))
        theta = lm.theta
        if moved < SETTLED_SIGMA and rounds > min(rereference, 1):
            break
    return problem, theta, evaluations, rounds, moved, linearisation


def _comparable(a: Problem, b: Problem) -> bool:
    """Whether two references of the noise agree within :data:`MAX_SIGMA_RATIO` per invariant:
    re-referencing moves the propagated noise by the change of the gains, which is small near
    a sound estimate; a large change means the estimate ran off (a degenerate valley)."""
    for n, s in a.sigma.items():
        ra = np.sqrt(np.mean(np.square(s)))
        rb = np.sqrt(np.mean(np.square(b.sigma[n])))
        if not (ra > 0 and rb > 0) or not 1 / MAX_SIGMA_RATIO < rb / ra < MAX_SIGMA_RATIO:
            return False
    return True


def _chi2(problem: Problem, theta: np.ndarray, T: np.ndarray) -> float:
    dof = problem.n_residuals - T.shape[1]
    return 2.0 * _cost(problem, theta) / dof if dof > 0 else 1.0


def fixed_point(
    problem: Problem,
    theta: np.ndarray,
    theta0: np.ndarray,
    typical: np.ndarray,
    basis: np.ndarray,
) -> FixedPoint:
    """Iterate the fit at ``theta`` to a fixed point and check it from the prior (module doc).

    ``basis`` (D, k): the observable directions the fit solved for (typical-scaled)."""
    problem, theta, evaluations, rounds, moved, linearisation = _settle(
        problem, theta, theta0, typical, basis
    )
    out: dict[str, Any] = {"rounds": rounds, "last_step_sigma": float(moved)}
    if rounds and moved >= SETTLED_SIGMA:
        out.update(converged=False, reason=(
            f"the estimate still moved by {moved:.2g} sigma after {rounds} rounds of "
            "re-referencing the noise at the estimate"))  # fmt: skip
        return FixedPoint(problem, theta, evaluations, out)
    # start-independence: from the prior on the settled problem
    T = typical[:, None] * basis
    # (from the settled answer's linearisation: near it, the restart needs no new one)
    lm = solve_lm(problem, theta0, T, linearisation=linearisation)
    evaluations += lm.evaluations
    gap = _distance(problem, lm.theta, theta) / np.sqrt(max(1.0, _chi2(problem, theta, T)))
    out["restart_gap_sigma"] = float(gap)
    if gap < SAME_ANSWER_SIGMA:
        out.update(converged=True, reason=None)
        return FixedPoint(problem, theta, evaluations, out)
    c_settled, c_restart = _cost(problem, theta), _cost(problem, lm.theta)
    if c_restart < c_settled:
        # the restart found a lower minimum: settle it and report the disagreement
        problem, theta, more, *_ = _settle(problem, lm.theta, theta0, typical, basis, 0)
        evaluations += more
    _, chi2 = covariance(problem, theta, T)
    out.update(converged=False, reason=(
        f"local minima: LM from the prior and from the settled estimate end {gap:.2g} sigma "
        f"apart (costs {min(c_settled, c_restart):.6g} and {max(c_settled, c_restart):.6g}); "
        f"the lower one is kept (chi2_red {chi2:.3g}); add positions or slews, or give a "
        "closer --prior"))  # fmt: skip
    return FixedPoint(problem, theta, evaluations, out)


def swarm_convergence(
    problem: Problem,
    theta: np.ndarray,
    theta0: np.ndarray,
    typical: np.ndarray,
    info_min: float,
    method: str,
) -> dict[str, Any]:
    """Did a swarm reach the minimum? LM from its answer tells (the answer itself is kept)."""
    report = analyze(problem, theta, typical, info_min=info_min)
    T = typical[:, None] * report.basis
    if not T.shape[1]:
        return {"converged": True, "reason": None, "evaluations": 0}
    lm = solve_lm(problem, projected_start(theta, theta0, typical, report.basis), T)
    gap = _distance(problem, lm.theta, theta) / np.sqrt(max(1.0, _chi2(problem, lm.theta, T)))
    per_direction = gap / np.sqrt(T.shape[1])
    out: dict[str, Any] = {"evaluations": lm.evaluations, "lm_gap_sigma": float(gap),
                           "lm_gap_sigma_per_direction": float(per_direction)}  # fmt: skip
    if per_direction < SAME_ANSWER_SIGMA:
        out.update(converged=True, reason=None)
    else:
        out.update(converged=False, reason=(
            f"the {method} answer is {gap:.2g} sigma ({per_direction:.2g} per observable "
            "direction) from the minimum LM finds from it: the swarm stopped short (use "
            "--polish or more --mc runs)"))  # fmt: skip
    return out
