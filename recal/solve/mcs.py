"""MCS: Monte Carlo repetition of the whole phased swarm optimisation, batched across runs.

Each run starts from the same prior with its own random stream (derived from ``--seed``), goes
through the phases, and repeats them in cycles until the indicator threshold, the cycle cap or a
stall. The runs are independent but advance in lock-step, so one objective call evaluates
fish x runs parameter vectors. The result is the per-coefficient mean and standard deviation
over the runs (the layout of seed 000 Table 3). The spread measures the solver's repeatability
on this data set, not the measurement uncertainty.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from recal.runtime.allocator import tune_allocator
from recal.runtime.pool import run_batches
from recal.solve.phases import Phase
from recal.solve.problem import Problem
from recal.solve.separable import search_blocks
from recal.solve.surrogate import SurrogateProblem, data_noise
from recal.solve.swarm import SwarmConfig

SWARM_METHODS = ("nafsa", "safsa", "oafsa")
#: The cycles end when the Gauss-Newton model is within this (chi^2 units) of the exact objective
#: at every run's position: after the first cycle from a prior it was off by 0.2-9, after the
#: second by at most 0.009 (30-position KVH-like captures with slews, seeds 3000 and 9001-9004).
MODEL_MATCH_CHI2 = 0.05


def solver_for(method: str) -> tuple[Callable, type[SwarmConfig]]:
    """(solver function, its config class) for a swarm method name."""
    if method == "nafsa":
        from recal.solve.nafsa import NafsaConfig, nafsa

        return nafsa, NafsaConfig
    if method == "safsa":
        from recal.solve.safsa import SafsaConfig, safsa

        return safsa, SafsaConfig
    if method == "oafsa":
        from recal.solve.oafsa import OafsaConfig, oafsa

        return oafsa, OafsaConfig
    raise ValueError(f"unknown swarm method {method!r}")


@dataclass(frozen=True)
class MCSResult:
    runs: np.ndarray  # (R, D) final parameters of every run
    mean: np.ndarray  # (D,)
    std: np.ndarray  # (D,) sample standard deviation over runs (0 for one run)
    objective: np.ndarray  # (R,) final swarm objective per run
    history: np.ndarray  # (R, total iterations + 1) best-so-far objective along all phases
    evaluations: int
    cycles: int
    #: (P, 2) row indices in ``runs`` of the antithetic pairs (each pair's data perturbed by
    #: opposite noise, :func:`recal.solve.surrogate.data_noise`), or None when the runs are
    #: independent (no perturbation); a batch's odd last run belongs to no pair
    pairs: np.ndarray | None = None


def _phase_objective(problem: Problem | SurrogateProblem, base: np.ndarray, transform: np.ndarray):
    """Objective over phase coordinates X (P, d); ``run`` (P,) says which run's base each row
    belongs to (the swarms evaluate uneven batches: only fish still trying, one centre per run)."""
    if isinstance(problem, SurrogateProblem):
        return problem.phase_objective(base, transform)

    def f(X: np.ndarray, run: np.ndarray) -> np.ndarray:
        return problem.objective(base[run] + X @ transform.T)

    return f


@dataclass(frozen=True)
class _Job:
    """Everything one batch of runs needs; inherited by forked workers, never pickled."""

    problem: Problem
    theta0: np.ndarray
    #: the phases, or a function of (the runs' parameters (R, D), the model the swarms search)
    phases: Sequence[Phase] | Callable[[np.ndarray, Problem | SurrogateProblem], Sequence[Phase]]
    solver: Callable
    config: SwarmConfig
    cycles: int
    stall_tol: float
    indicator_threshold: float
    sizes: tuple[int, ...]  # runs per batch
    seeds: tuple[np.random.SeedSequence, ...]
    #: (D,) typical changes: linearise the residuals about the runs' mean every cycle
    #: (recal.solve.surrogate); None: the exact objective throughout
    linearise: np.ndarray | None = None
    #: each run on its own data, perturbed by the measurement noise (recal.solve.surrogate.data_noise)
    perturb: bool = False
    #: the first cycle's model, about theta0 and without noise: the same for every batch, so
    #: taken once before the batches fork
    first: SurrogateProblem | None = None


@dataclass(frozen=True)
class _BatchOutcome:
    final: np.ndarray  # (R, D)
    objective: np.ndarray  # (R,)
    history: np.ndarray  # (R, iterations + 1)
    evaluations: int
    cycles: int


def _run_batch(job: _Job, b: int, progress: Callable[[float], None] | None = None) -> _BatchOutcome:
    problem, R = job.problem, job.sizes[b]
    rng = np.random.default_rng(job.seeds[b])
    base = np.repeat(job.theta0[None], R, axis=0)
    runs = np.arange(R)
    noise = data_noise(problem, R, rng) if job.perturb else None
    model: Problem | SurrogateProblem = problem
    if job.first is not None:
        model = replace(job.first, noise=noise)
    # each run on its own data; the start is the same for all: one row of residuals
    prev, plain = _exact_objectives(model, job.theta0[None], runs)
    hist = [prev[:, None]]
    evaluations = used_cycles = 0
    reported = 0.0  # runs reported done (fractions)
    for cycle in range(job.cycles):
        if job.linearise is not None and cycle:  # the expansion taken where the runs are now
            model = SurrogateProblem.at(problem, base.mean(axis=0), job.linearise, noise)
            evaluations += model.evaluations
        current = job.phases(base, model) if callable(job.phases) else job.phases
        for ph in current:
            step, f_step, history, n_eval = _search(job, model, base, ph, rng)
            evaluations += n_eval
            better = f_step < _objective(model, base, runs)
            base = np.where(better[:, None], base + step @ ph.transform.T, base)
            hist.append(np.minimum.accumulate(history[:, 1:], axis=1))
            done = R / (len(current) * job.cycles)
            _report(progress, done)
            reported += done
        # the exact objective (each run on its own data) decides the stall
        now, plain = _exact_objectives(model, base, runs)
        used_cycles = cycle + 1
        # seed 000 section 3.3.2: repeat the phases until every run's eq. (14) indicator is
        # below the threshold (the paper uses 1e-8) or the indicator stops improving
        if job.indicator_threshold > 0:  # indicators are >= 0: a threshold of 0 never ends
            indicators = np.max(np.stack(list(problem.indicator(base).values())), axis=0)
            if np.all(indicators < job.indicator_threshold):
                break
        if np.all(now >= prev * (1.0 - job.stall_tol)):
            break
        if isinstance(model, SurrogateProblem) and model.quadratic:
            # the model matches the exact objective where every run now is: its minimisers are
            # the exact ones (to a few hundredths of a sigma), another cycle would repeat them
            mismatch = np.abs(now - model.objective(base, runs)) * problem.objective_dof
            if np.max(mismatch) < MODEL_MATCH_CHI2:
                break
        prev = now
    if R - reported > 1e-9:  # the cycles stopped early: the batch's runs are all done
        _report(progress, R - reported)
    history = np.minimum.accumulate(np.concatenate(hist, axis=1), axis=1)
    return _BatchOutcome(base, plain, history, evaluations, used_cycles)


def _search(
    job: _Job,
    model: Problem | SurrogateProblem,
    base: np.ndarray,
    ph: Phase,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One phase's swarm for every run from ``base``: (step (R, d) in phase coordinates, the
    objective there (R,), best-so-far history (R, iterations + 1), evaluations). A separable
    phase on a quadratic model is searched block by block, side by side
    (:mod:`recal.solve.separable`); otherwise jointly."""
    if ph.blocks and isinstance(model, SurrogateProblem) and model.quadratic:
        c, g, H = model.phase_quadratic(base, ph.transform)
        found = search_blocks(job.solver, job.config, rng, c, g, H, ph.visual, ph.blocks)
        return found.step, found.objective, found.history, found.evaluations
    f = _phase_objective(model, base, ph.transform)
    center = np.zeros((base.shape[0], ph.transform.shape[1]))
    res = job.solver(f, center, ph.visual, rng, job.config, with_runs=True)
    return res.best_x, res.best_f, res.history, res.evaluations


def _objective(model: Problem | SurrogateProblem, theta: np.ndarray, runs: np.ndarray):
    if isinstance(model, SurrogateProblem):
        return model.objective(theta, runs)
    return model.objective(theta)


def _exact_objectives(
    model: Problem | SurrogateProblem, theta: np.ndarray, runs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The exact objective of every run at ``theta`` ((R, D), or (1, D) for all), on its own
    data and on the data as measured, (R,) each."""
    if isinstance(model, SurrogateProblem):
        own, measured = model.exact_objectives(theta, runs)
    else:
        own = measured = model.objective(theta)
    shape = (runs.size,)
    return np.broadcast_to(own, shape).copy(), np.broadcast_to(measured, shape).copy()


def _report(progress: Callable[[float], None] | None, runs: float) -> None:
    """Runs completed (fractions), to the caller or, in a worker, to the shared counter."""
    if progress is not None:
        progress(runs)


def _surrogate_steps(
    problem: Problem, theta0: np.ndarray, linearise: np.ndarray | None, perturb: bool
) -> np.ndarray | None:
    """The typical changes the surrogate needs, or None when the exact objective serves (nothing
    to linearise and no perturbation)."""
    if linearise is not None or perturb:
        return np.asarray(linearise if linearise is not None else problem.layout.typical(theta0))
    return None


def run_mcs(
    problem: Problem,
    theta0: np.ndarray,
    phases: Sequence[Phase] | Callable[[np.ndarray, Problem | SurrogateProblem], Sequence[Phase]],
    method: str = "nafsa",
    runs: int = 100,
    seed: int = 0,
    config: SwarmConfig | None = None,
    cycles: int = 3,
    stall_tol: float = 1e-3,
    indicator_threshold: float = 0.0,
    batch: int = 50,
    workers: int | None = None,
    progress: Callable[[float], None] | None = None,
    linearise: np.ndarray | None = None,
    perturb: bool = False,
) -> MCSResult:
    """Run ``runs`` independent phased optimisations from ``theta0`` and summarise them.

    ``phases`` may be a function of the runs' current parameters (R, D) and of the model the
    cycle's swarms search (the problem, or its :class:`recal.solve.surrogate.SurrogateProblem`),
    called at the start of every cycle, so the search directions and Visual follow the runs
    (the whitened phase, taken where the model is).
    Cycles end when every run's eq. (14) indicator is below ``indicator_threshold`` (all
    invariants), when no run improved the objective by ``stall_tol`` (relative), or after
    ``cycles``.

    Runs are processed ``batch`` at a time (larger batches: fewer, larger objective calls).
    Each batch has its own generator spawned from ``seed``, so the result depends only on seed,
    runs and batch -- not on ``workers``, the number of forked processes that run batches side by
    side (default: one per available core, at most one per batch; 1 = in this process).
    ``progress`` receives the number of runs completed (fractions while a batch goes through its
    phases; forked workers count into a shared value the parent polls a few times a second).

    ``linearise`` (D,) typical changes: the swarms search a
    :class:`recal.solve.surrogate.SurrogateProblem`, the residuals linearised about the batch's
    mean and refreshed at the start of every cycle (a Gauss-Newton model; the seed's eq. (14)
    objective: the motion invariants only); the stall test and the reported objective use the
    exact problem. A separable phase on that model is searched block by block
    (:mod:`recal.solve.separable`).
    ``perturb``: every run minimises on its own data set, the measurements perturbed by their
    noise (antithetic pairs; :func:`recal.solve.surrogate.data_noise`), so the spread over the runs
    estimates the measurement uncertainty, not only the solver's repeatability.
    """
    tune_allocator()
    solver, config_cls = solver_for(method)
    n_batches = (runs + batch - 1) // batch
    steps = _surrogate_steps(problem, theta0, linearise, perturb)
    job = _Job(
        problem=problem, theta0=theta0, phases=phases, solver=solver,
        config=config or config_cls(), cycles=cycles, stall_tol=stall_tol,
        indicator_threshold=indicator_threshold,
        sizes=tuple(min(batch, runs - b * batch) for b in range(n_batches)),
        seeds=tuple(np.random.SeedSequence(seed).spawn(n_batches)),
        linearise=steps, perturb=perturb,
        first=None if steps is None else SurrogateProblem.at(problem, theta0, steps),
    )  # fmt: skip
    outcomes: list[_BatchOutcome] = run_batches(
        lambda b, report: _run_batch(job, b, report), n_batches, workers, progress
    )
    width = max(o.history.shape[1] for o in outcomes)
    history = np.concatenate(
        [np.pad(o.history, ((0, 0), (0, width - o.history.shape[1])), mode="edge")
         for o in outcomes]
    )  # fmt: skip
    all_runs = np.concatenate([o.final for o in outcomes])
    pairs = None
    if job.perturb:  # data_noise pairs rows (0, 1), (2, 3), ... within each batch
        starts = np.cumsum((0,) + job.sizes[:-1])
        first = np.concatenate([o + np.arange(0, s - 1, 2) for o, s in zip(starts, job.sizes)])
        pairs = np.stack([first, first + 1], axis=1).astype(int)
    std = all_runs.std(axis=0, ddof=1) if runs > 1 else np.zeros(all_runs.shape[1])
    return MCSResult(
        all_runs,
        all_runs.mean(axis=0),
        std,
        np.concatenate([o.objective for o in outcomes]),
        history,
        sum(o.evaluations for o in outcomes) + (job.first.evaluations if job.first else 0),
        max(o.cycles for o in outcomes),
        pairs,
    )
