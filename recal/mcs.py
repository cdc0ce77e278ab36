"""MCS: Monte Carlo repetition of the whole phased swarm optimisation, batched across runs.

Each run starts from the same prior with its own random stream (derived from ``--seed``), goes
through the phases, and repeats them in cycles until the indicator threshold, the cycle cap or a
stall. The runs are independent but advance in lock-step, so one objective call evaluates
fish x runs parameter vectors. The result is the per-coefficient mean and standard deviation
over the runs (the layout of seed 000 Table 3). The spread measures the solver's repeatability
on this data set, not the measurement uncertainty.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from recal.perf import tune_allocator
from recal.phases import Phase
from recal.problem import Problem
from recal.swarm import SwarmConfig

SWARM_METHODS = ("nafsa", "safsa", "oafsa")


def solver_for(method: str) -> tuple[Callable, type[SwarmConfig]]:
    """(solver function, its config class) for a swarm method name."""
    if method == "nafsa":
        from recal.nafsa import NafsaConfig, nafsa

        return nafsa, NafsaConfig
    if method == "safsa":
        from recal.safsa import SafsaConfig, safsa

        return safsa, SafsaConfig
    if method == "oafsa":
        from recal.oafsa import OafsaConfig, oafsa

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


def _phase_objective(problem: Problem, base: np.ndarray, transform: np.ndarray):
    """Objective over phase coordinates X (P, d); ``run`` (P,) says which run's base each row
    belongs to (the swarms evaluate uneven batches: only fish still trying, one centre per run)."""

    def f(X: np.ndarray, run: np.ndarray) -> np.ndarray:
        return problem.objective(base[run] + X @ transform.T)

    return f


@dataclass(frozen=True)
class _Job:
    """Everything one batch of runs needs; inherited by forked workers, never pickled."""

    problem: Problem
    theta0: np.ndarray
    phases: Sequence[Phase] | Callable[[np.ndarray], Sequence[Phase]]
    solver: Callable
    config: SwarmConfig
    cycles: int
    stall_tol: float
    indicator_threshold: float
    sizes: tuple[int, ...]  # runs per batch
    seeds: tuple[np.random.SeedSequence, ...]


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
    hist = [problem.objective(base)[:, None]]
    prev = hist[0][:, 0]
    evaluations = used_cycles = 0
    for cycle in range(job.cycles):
        current = job.phases(base) if callable(job.phases) else job.phases
        for ph in current:
            f = _phase_objective(problem, base, ph.transform)
            center = np.zeros((R, ph.transform.shape[1]))
            res = job.solver(f, center, ph.visual, rng, job.config, with_runs=True)
            evaluations += res.evaluations
            better = res.best_f < problem.objective(base)
            base = np.where(better[:, None], base + res.best_x @ ph.transform.T, base)
            hist.append(np.minimum.accumulate(res.history[:, 1:], axis=1))
            if progress:
                progress(R / (len(current) * job.cycles))
        now = problem.objective(base)
        used_cycles = cycle + 1
        # seed 000 section 3.3.2: repeat the phases until every run's eq. (14) indicator is
        # below the threshold (the paper uses 1e-8) or the indicator stops improving
        indicators = np.max(np.stack(list(problem.indicator(base).values())), axis=0)
        if np.all(indicators < job.indicator_threshold):
            break
        if np.all(now >= prev * (1.0 - job.stall_tol)):
            break
        prev = now
    history = np.minimum.accumulate(np.concatenate(hist, axis=1), axis=1)
    return _BatchOutcome(base, problem.objective(base), history, evaluations, used_cycles)


_FORK_JOB: _Job | None = None  # set in the parent just before forking the workers


def _init_worker() -> None:
    # A BLAS thread pool inherited through fork oversubscribes the cores (and can spin); the
    # matrices here are tiny, so each worker uses one BLAS thread.
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def _run_forked(b: int) -> _BatchOutcome:
    assert _FORK_JOB is not None
    return _run_batch(_FORK_JOB, b)


def _default_workers(n_batches: int) -> int:
    if "fork" not in mp.get_all_start_methods():
        return 1
    return max(1, min(n_batches, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                      else (os.cpu_count() or 1)))  # fmt: skip


def run_mcs(
    problem: Problem,
    theta0: np.ndarray,
    phases: Sequence[Phase] | Callable[[np.ndarray], Sequence[Phase]],
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
) -> MCSResult:
    """Run ``runs`` independent phased optimisations from ``theta0`` and summarise them.

    ``phases`` may be a function of the runs' current parameters (R, D), called at the start of
    every cycle, so the search directions and Visual follow the runs (the whitened phase).
    Cycles end when every run's eq. (14) indicator is below ``indicator_threshold`` (all
    invariants), when no run improved the objective by ``stall_tol`` (relative), or after
    ``cycles``.

    Runs are processed ``batch`` at a time (larger batches: fewer, larger objective calls).
    Each batch has its own generator spawned from ``seed``, so the result depends only on seed,
    runs and batch -- not on ``workers``, the number of forked processes that run batches side by
    side (default: one per available core, at most one per batch; 1 = in this process).
    ``progress`` receives the number of runs completed (fractions while a batch goes through its
    phases when running in this process).
    """
    tune_allocator()
    solver, config_cls = solver_for(method)
    n_batches = (runs + batch - 1) // batch
    job = _Job(
        problem, theta0, phases, solver, config or config_cls(), cycles, stall_tol,
        indicator_threshold,
        tuple(min(batch, runs - b * batch) for b in range(n_batches)),
        tuple(np.random.SeedSequence(seed).spawn(n_batches)),
    )  # fmt: skip
    workers = _default_workers(n_batches) if workers is None else max(1, min(workers, n_batches))
    outcomes: list[_BatchOutcome] = []
    if workers == 1:
        from threadpoolctl import threadpool_limits  # 70 ms to import: only on this path

        # the same one-thread BLAS as the workers: the matrices are tiny, and a BLAS pool
        # spinning on a loaded machine costs 2-3x the wall time (restored on return)
        with threadpool_limits(1, user_api="blas"):
            for b in range(n_batches):
                outcomes.append(_run_batch(job, b, progress))
    else:
        global _FORK_JOB
        _FORK_JOB = job
        try:
            ctx = mp.get_context("fork")
            with ProcessPoolExecutor(
                max_workers=workers, mp_context=ctx, initializer=_init_worker
            ) as pool:
                futures = [pool.submit(_run_forked, b) for b in range(n_batches)]
                for b, fut in enumerate(futures):
                    outcomes.append(fut.result())
                    if progress:
                        progress(job.sizes[b])
        finally:
            _FORK_JOB = None
    width = max(o.history.shape[1] for o in outcomes)
    history = np.concatenate(
        [np.pad(o.history, ((0, 0), (0, width - o.history.shape[1])), mode="edge")
         for o in outcomes]
    )  # fmt: skip
    all_runs = np.concatenate([o.final for o in outcomes])
    std = all_runs.std(axis=0, ddof=1) if runs > 1 else np.zeros(all_runs.shape[1])
    return MCSResult(
        all_runs,
        all_runs.mean(axis=0),
        std,
        np.concatenate([o.objective for o in outcomes]),
        history,
        sum(o.evaluations for o in outcomes),
        max(o.cycles for o in outcomes),
    )
