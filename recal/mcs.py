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
    batch: int = 100,
    progress: Callable[[int], None] | None = None,
) -> MCSResult:
    """Run ``runs`` independent phased optimisations from ``theta0`` and summarise them.

    ``phases`` may be a function of the runs' current parameters (R, D), called at the start of
    every cycle, so the search directions and Visual follow the runs (the whitened phase).
    Cycles end when every run's eq. (14) indicator is below ``indicator_threshold`` (all
    invariants), when no run improved the objective by ``stall_tol`` (relative), or after
    ``cycles``. Runs are processed ``batch`` at a time; larger batches mean fewer, larger objective calls.
    Each batch has its own generator spawned from ``seed``, so the result depends only on seed,
    runs and batch. ``progress`` receives the number of runs completed (fractions while a batch
    goes through its phases).
    """
    tune_allocator()
    solver, config_cls = solver_for(method)
    config = config or config_cls()
    seeds = np.random.SeedSequence(seed).spawn((runs + batch - 1) // batch)
    finals, objectives, histories, evaluations, used_cycles = [], [], [], 0, 0
    for b, ss in enumerate(seeds):
        rng = np.random.default_rng(ss)
        R = min(batch, runs - b * batch)
        base = np.repeat(theta0[None], R, axis=0)
        hist = [problem.objective(base)[:, None]]
        prev = hist[0][:, 0]
        reported = 0.0
        for cycle in range(cycles):
            current = phases(base) if callable(phases) else phases
            for ph in current:
                f = _phase_objective(problem, base, ph.transform)
                center = np.zeros((R, ph.transform.shape[1]))
                res = solver(f, center, ph.visual, rng, config, with_runs=True)
                evaluations += res.evaluations
                better = res.best_f < problem.objective(base)
                base = np.where(better[:, None], base + res.best_x @ ph.transform.T, base)
                hist.append(np.minimum.accumulate(res.history[:, 1:], axis=1))
                if progress:
                    step = R / (len(current) * cycles)
                    progress(step)
                    reported += step
            now = problem.objective(base)
            used_cycles = max(used_cycles, cycle + 1)
            # seed 000 section 3.3.2: repeat the phases until every run's eq. (14) indicator is
            # below the threshold (the paper uses 1e-8) or the indicator stops improving
            indicators = np.max(np.stack(list(problem.indicator(base).values())), axis=0)
            if np.all(indicators < indicator_threshold):
                break
            if np.all(now >= prev * (1.0 - stall_tol)):
                break
            prev = now
        finals.append(base)
        objectives.append(problem.objective(base))
        histories.append(np.minimum.accumulate(np.concatenate(hist, axis=1), axis=1))
        if progress:
            progress(R - reported)
    width = max(h.shape[1] for h in histories)
    history = np.concatenate(
        [np.pad(h, ((0, 0), (0, width - h.shape[1])), mode="edge") for h in histories]
    )
    all_runs = np.concatenate(finals)
    std = all_runs.std(axis=0, ddof=1) if runs > 1 else np.zeros(all_runs.shape[1])
    return MCSResult(
        all_runs,
        all_runs.mean(axis=0),
        std,
        np.concatenate(objectives),
        history,
        evaluations,
        used_cycles,
    )
