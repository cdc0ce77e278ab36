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

A swarm (MCS-NAFSA, SAFSA, OAFSA) is checked by :func:`swarm_convergence`: LM from its answer
(the Monte Carlo mean of N runs) finds the minimum, and the gap between the two is compared
with the mean's own sampling error, estimated from the runs, in the k directions the swarm
searched (whitened: in units of the reported 1-sigma). Each run fits the data perturbed by
their noise, in antithetic pairs (eps, -eps) whose mean is free of the perturbation to first
order, so the independent samples are the N/2 pair means (with ``--paper`` the N runs, all on
the same data); a batch's odd last run is left out of the test. With n samples, d their mean's
gap to LM's minimum and S their covariance, the gap less :data:`LM_TOLERANCE_SIGMA` (LM's own
convergence tolerance, 0.05 sigma, taken off along the gap) is tested at the false-rejection
rate :data:`FALSE_REJECTION` (1e-3: a swarm that did reach the minimum is called unconverged
once in a thousand calibrations):

* n > k: Hotelling's T^2 = n d^T S^-1 d against k (n - 1) / (n - k) F_{k, n-k}(1 - 1e-3), the
  exact test of a mean whose covariance is estimated from n samples (it tends to the
  chi-square on k degrees of freedom as n grows: the threshold follows from the runs, 162 for
  50 pairs over 24 directions, 43 over 9, 51 in the limit for 24);
* 2 <= n <= k: n samples cannot estimate a k x k covariance, so each direction is tested on its
  own variance, the largest |t| against Student's t_{n-1}(1 - 1e-3 / 2k) (Bonferroni: the same
  rate over the k directions, a weaker test);
* n < 2 (a single run, or a single pair): there is no spread, so the convergence cannot be
  checked from the runs; the answer is accepted only within LM's tolerance, which a single run
  on perturbed data, off by one draw of the noise, does not meet.

The old rule (the gap over sqrt(k) below 0.5 sigma: 2.45 sigma in total at k = 24) accepted a
swarm stopped after one cycle of 8 iterations 0.86 sigma short over 9 directions, whose mean's
sampling error was 0.25 sigma (T^2 125 against 43; ``tests/recal/test_convergence_swarm.py``).
When the test fails, the swarm's own objective (:meth:`recal.solve.problem.Problem.objective`)
says why: lower at LM's minimum, the swarm stopped short. By default that objective is the
least squares LM minimises (chi^2 / (R - 1)), so the two share their minimum; with ``--paper``
it is seed 000 eq. 14 per invariant over one noise floor, which weighs the residuals
differently: lower at the swarm's answer, the two objectives have different minima (with
slews about half a sigma apart, which no number of runs or iterations closes; ``--polish``
gives the least-squares one).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from scipy import stats

from recal.solve.lm import RELINEARISE_SIGMA, covariance, solve_lm
from recal.solve.observability import analyze, jacobian
from recal.solve.problem import Problem

#: A round that moves the estimate by less than this (Mahalanobis norm, sigma) has settled.
SETTLED_SIGMA = 0.05
#: Rounds before giving up: each is one LM run, usually 1-3 are needed.
MAX_ROUNDS = 8
#: Rounds that re-reference the noise at the estimate before the problem is kept fixed.
REREFERENCE = 2
#: Re-referencing that changes an invariant's RMS noise by more than this factor is refused.
MAX_SIGMA_RATIO = 2.0
#: Two answers closer than this (Mahalanobis norm, sigma) are the same answer, for LM's restart
#: from the prior: LM is deterministic, and another minimum is far away.
SAME_ANSWER_SIGMA = 0.5
#: A swarm whose Monte Carlo mean did reach the minimum is called unconverged this often, by
#: chance of its runs (the false-rejection rate of :func:`mean_test`).
FALSE_REJECTION = 1e-3
#: LM's own convergence tolerance (sigma): with slews its answer is settled once a new
#: linearisation moves it by less than this (``recal.solve.lm.RELINEARISE_SIGMA``; the fixed
#: point's :data:`SETTLED_SIGMA` is the same 0.05). A swarm is not asked to agree with LM closer
#: than LM agrees with itself: the gap is tested beyond it.
LM_TOLERANCE_SIGMA = RELINEARISE_SIGMA


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
    runs: np.ndarray | None = None,
    pairs: np.ndarray | None = None,
    basis: np.ndarray | None = None,
    J: np.ndarray | None = None,
) -> dict[str, Any]:
    """Did a swarm reach the minimum? LM from its answer finds the minimum, and the gap is
    tested against the Monte Carlo mean's own sampling error (module doc; the answer itself
    is kept).

    ``theta``: the swarm's answer, the mean of ``runs`` (R, D) (None: ``theta`` alone, one
    run). ``pairs`` (P, 2): the runs' antithetic pairs (:attr:`recal.solve.mcs.MCSResult.pairs`;
    None: the runs are independent). ``basis`` (D, k): the directions the swarm searched
    (typical-scaled; None: those observable at ``theta``). ``J``: the observability Jacobian at
    ``theta`` (:func:`recal.solve.observability.typical_jacobian`) when the caller has it."""
    report = analyze(problem, theta, typical, info_min=info_min, J=J)
    T = typical[:, None] * report.basis
    if not T.shape[1]:
        return {"converged": True, "reason": None, "evaluations": 0}
    lm = solve_lm(problem, projected_start(theta, theta0, typical, report.basis), T)
    chi2 = max(1.0, _chi2(problem, lm.theta, T))
    gap = _distance(problem, lm.theta, theta) / np.sqrt(chi2)
    out: dict[str, Any] = {"lm_gap_sigma": float(gap)}
    B = report.basis if basis is None else basis
    samples = np.atleast_2d(theta if runs is None else runs)
    if pairs is not None and len(pairs) and runs is not None:
        samples = 0.5 * (runs[pairs[:, 0]] + runs[pairs[:, 1]])
    # whitened coordinates of the tested directions (first order: the Gauss-Newton metric, in
    # units of the reported 1-sigma), so a gap's length is its Mahalanobis norm
    J = jacobian(problem, lm.theta, (typical[:, None] * B).T) / np.sqrt(chi2)
    out["evaluations"] = lm.evaluations + 2 * B.shape[1]
    _, s, vt = np.linalg.svd(J, full_matrices=False)
    W = (s[:, None] * vt) @ B.T / typical  # (k, D): parameter change -> whitened coordinates
    test = mean_test(W @ (samples - lm.theta).T, len(samples) if runs is None else len(runs))
    out["test"] = test
    if test["statistic"] <= test["threshold"]:
        out.update(converged=True, reason=None)
    elif test["samples"] < 2:
        out.update(converged=False, reason=(
            f"the {method} answer is {test['gap_sigma']:.2g} sigma from the minimum LM finds "
            f"from it, beyond LM's own tolerance ({LM_TOLERANCE_SIGMA} sigma), and with "
            f"{test['runs']} run(s) ({test['samples']} independent sample: a single run or "
            "antithetic pair) there is no spread to tell the Monte Carlo sampling error "
            "from a swarm that stopped short (use more --mc runs, or --polish)"))  # fmt: skip
    else:
        # which minimum is lower by the swarm's own objective (recal.solve.problem.Problem.
        # objective: the least squares, or with --paper eq. 14 per invariant over its noise
        # floor)? LM's: the swarm stopped short of it; the swarm's answer: with eq. 14 the two
        # objectives weigh the residuals differently and their minima differ (with slews, by
        # about half a sigma), however long the swarm searches
        f_answer, f_lm = problem.objective(np.stack([theta, lm.theta]))
        out["swarm_objective"] = {"answer": float(f_answer), "lm_minimum": float(f_lm)}
        beyond = (f"beyond its Monte Carlo sampling error ({test['name']} "
                  f"{test['statistic']:.3g} > {test['threshold']:.3g} over {test['directions']} "
                  f"directions, {test['samples']} independent samples of {test['runs']} runs, "
                  f"false-rejection rate {FALSE_REJECTION:g})")  # fmt: skip
        if f_lm < f_answer:
            why = "the swarm stopped short (use --polish or more --iterations)"
        elif problem.paper_objective:
            why = ("the swarm's own objective is lower at its answer than there: the swarm's "
                   "objective (seed 000 eq. 14, each invariant's squared residuals over their "
                   "count and one noise floor) and the least squares LM minimises (each "
                   "residual over its own sigma) have different minima (use --polish for the "
                   "least-squares one, whose covariance is reported)")  # fmt: skip
        else:
            why = ("the least squares the swarm minimised is no lower at LM's minimum than at "
                   "its answer: a flat valley LM stopped in at its tolerance (use --polish)")  # fmt: skip
        out.update(converged=False, reason=(
            f"the {method} answer is {test['gap_sigma']:.2g} sigma from the minimum LM finds "
            f"from it, {beyond}: {why}"))  # fmt: skip
    return out


def mean_test(w: np.ndarray, runs: int, alpha: float = FALSE_REJECTION) -> dict[str, Any]:
    """Is the mean of ``w`` (k, n) -- n independent samples of the gap to LM's minimum, in
    whitened coordinates (sigma) -- zero within its sampling error, beyond LM's tolerance?

    The mean's gap is shortened by :data:`LM_TOLERANCE_SIGMA` along itself (zero when shorter),
    then: n > k, Hotelling's T^2 = n d' S^-1 d' (S: the samples' covariance) against
    k (n - 1) / (n - k) F_{k, n-k}(1 - alpha), the exact test of a mean whose covariance is
    estimated from n samples (chi-square on k degrees of freedom as n grows); 2 <= n <= k, the
    samples cannot estimate a k x k covariance: the largest |t| over the k directions (each
    direction's variance from the samples) against Student's t_{n-1}(1 - alpha / 2k)
    (Bonferroni: the same false-rejection rate over the k directions); n < 2, no spread: the
    gap itself against the tolerance."""
    k, n = w.shape
    d = w.mean(axis=1)
    norm = float(np.linalg.norm(d))
    shortened = d * max(0.0, 1.0 - LM_TOLERANCE_SIGMA / norm) if norm > 0 else d
    out: dict[str, Any] = {"runs": int(runs), "samples": int(n), "directions": int(k),
                           "gap_sigma": norm, "lm_tolerance_sigma": LM_TOLERANCE_SIGMA,
                           "false_rejection": alpha}  # fmt: skip
    if n < 2:
        out.update(name="gap (no spread: not checkable from the runs)", statistic=norm,
                   threshold=LM_TOLERANCE_SIGMA)  # fmt: skip
        return out
    S = np.atleast_2d(np.cov(w, ddof=1))
    S = S + np.eye(k) * 1e-12 * max(float(np.trace(S)) / k, 1e-300)  # a direction with no spread
    if n > k:
        statistic = float(n * shortened @ np.linalg.solve(S, shortened))
        threshold = float(k * (n - 1) / (n - k) * stats.f.ppf(1.0 - alpha, k, n - k))
        out.update(name="Hotelling T^2", statistic=statistic, threshold=threshold)
    else:
        t = shortened / np.sqrt(np.diag(S) / n)
        threshold = float(stats.t.ppf(1.0 - alpha / (2 * k), n - 1))
        out.update(name="max |t| (Bonferroni)", statistic=float(np.max(np.abs(t))),
                   threshold=threshold)  # fmt: skip
    out["sampling_sigma"] = float(np.sqrt(np.trace(S) / n))
    return out
