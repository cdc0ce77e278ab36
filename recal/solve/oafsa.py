"""Optimal artificial fish swarm algorithm, OAFSA (seed 000 section 2.2; seed 002 section 3).

OAFSA is SAFSA (:mod:`recal.solve.safsa`) with a decaying Visual and Step, eqs. (1)-(3):

    Visual = Visual * lambda + Visual_min        (1)
    Step   = Step * lambda + Step_min            (2)
    lambda = exp(-3 * G / G_max)                 (3)

with ``G`` the current and ``G_max`` the maximum iteration. Applied recursively (Visual on the
right being the previous iteration's value) eq. 1 multiplies Visual by a product of lambdas that
becomes ~exp(-1.5 G_max) and the swarm freezes within a handful of iterations, which is clearly not
what the papers describe ("at the beginning the Visual and Step are relatively large ... with the
increase of iterations both become less"). We therefore use the non-recursive reading
``Visual_G = Visual_0 * lambda(G) + Visual_min`` and ``Step_G = Step_0 * lambda(G) + Step_min``:
Visual and Step decay from ``Visual_0 + Visual_min`` to ``Visual_0 * e^-3 + Visual_min``.

**Secondary initialisation** (seed 000 section 2.2, seed 002 section 3.2). The papers watch the
indicator until it "presents a divergence tendency", store the fish parameters at the lowest
indicator point and reload them *manually* before running the swarm again. Here this is automatic
and per run: when a run's best-so-far has not improved for ``reinit_patience`` iterations, or the
best fish of its *current* swarm has got worse for ``divergence_iterations`` consecutive
iterations (the divergence tendency; the best-so-far itself never rises), the run's swarm is
re-initialised around its stored best (the *bulletin*) as ``X_Best + reinit_factor * Visual_0 *
U(-1, 1)``, Visual_0 and Step_0 are reset to ``reinit_factor`` times their initial values and the
lambda schedule restarts (``G = 0``, ``G_max`` = the iterations the run has left). This happens
at most ``max_reinit`` times per run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recal.solve.safsa import SafsaConfig, afsa_iteration
from recal.solve.swarm import Objective, SwarmBook, SwarmResult, uniform


@dataclass(frozen=True)
class OafsaConfig(SafsaConfig):
    """OAFSA settings: :class:`recal.solve.safsa.SafsaConfig` plus eqs. (1)-(3) and the secondary
    initialisation (normalised units, Visual = 1 is the Visual vector passed in).

    Attributes:
        visual_min: Visual_min of eq. 1 (default 0.01).
        step_min: Step_min of eq. 2 (default 0.005).
        reinit_patience: re-initialise a run whose best-so-far has not improved for this many
            iterations (default 8; 0 disables this trigger).
        divergence_iterations: re-initialise a run whose current best fish got worse in this many
            consecutive iterations (default 5; 0 disables this trigger).
        max_reinit: at most this many secondary initialisations per run (default 1; 0 = none).
        reinit_factor: the new swarm's spread and the new Visual_0 and Step_0, relative to the
            initial ones (default 0.3).
    """

    visual_min: float = 0.01
    step_min: float = 0.005
    reinit_patience: int = 8
    divergence_iterations: int = 5
    max_reinit: int = 1
    reinit_factor: float = 0.3

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (self.visual_min >= 0 and self.step_min >= 0):
            raise ValueError("visual_min and step_min must be >= 0")
        for name in ("reinit_patience", "divergence_iterations", "max_reinit"):
            value = getattr(self, name)
            if int(value) != value or value < 0:
                raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
        if not self.reinit_factor > 0:
            raise ValueError(f"reinit_factor must be > 0, got {self.reinit_factor!r}")


def oafsa(
    objective: Objective,
    center: np.ndarray,
    visual: np.ndarray,
    rng: np.random.Generator,
    config: OafsaConfig | None = None,
    *,
    with_runs: bool = False,
) -> SwarmResult:
    """Minimise ``objective`` with OAFSA (eqs. 1-3 + automated secondary initialisation).

    Arguments as :func:`recal.solve.safsa.safsa`. ``visual_history`` of the result holds
    ``Visual_G / Visual`` per run, including the restarts.
    """
    cfg = OafsaConfig() if config is None else config
    book = SwarmBook(objective, center, visual, cfg, with_runs)
    runs, dim, fish = book.runs, book.dim, cfg.fish
    z = uniform(rng, (runs, fish, dim))
    fz = book.evaluate(z, np.arange(runs))

    factor = np.ones(runs)  # Visual_0 and Step_0 relative to the configured ones
    g = np.zeros(runs)  # G, iterations since the (re)start of the lambda schedule
    g_max = np.full(runs, float(max(cfg.iterations, 1)))  # G_max of the current schedule
    reinits = np.zeros(runs, dtype=int)
    stagnant = np.zeros(runs, dtype=int)  # iterations without a new best-so-far
    rising = np.zeros(runs, dtype=int)  # consecutive rises of the current swarm's best fish
    swarm_best = fz.min(axis=1)

    def schedule() -> tuple[np.ndarray, np.ndarray]:
        lam = np.exp(-3.0 * g / g_max)  # eq. 3
        vis = cfg.visual * factor * lam + cfg.visual_min  # eq. 1
        step = cfg.step * factor * lam + cfg.step_min  # eq. 2
        return vis, step

    book.record(schedule()[0] / cfg.visual)
    while book.active.any():
        idx = book.active_runs()
        vis, step = schedule()
        best_before = book.best_f[idx].copy()
        zi, fi = afsa_iteration(
            book, rng, idx, z[idx], fz[idx], vis[idx], step[idx], cfg.delta, cfg.tries
        )
        z[idx], fz[idx] = zi, fi
        g[idx] += 1
        improved = book.best_f[idx] < best_before
        stagnant[idx] = np.where(improved, 0, stagnant[idx] + 1)
        current = fi.min(axis=1)
        rising[idx] = np.where(current > swarm_best[idx], rising[idx] + 1, 0)
        swarm_best[idx] = current
        book.record(schedule()[0] / cfg.visual)

        # Secondary initialisation of the runs that are still going and meet a trigger.
        trigger = np.zeros(runs, dtype=bool)
        if cfg.reinit_patience > 0:
            trigger |= stagnant >= cfg.reinit_patience
        if cfg.divergence_iterations > 0:
            trigger |= rising >= cfg.divergence_iterations
        trigger &= book.active & (reinits < cfg.max_reinit)
        if trigger.any():
            r = np.flatnonzero(trigger)
            factor[r] = cfg.reinit_factor
            g[r] = 0.0
            g_max[r] = max(cfg.iterations - book.iteration, 1)
            reinits[r] += 1
            stagnant[r] = 0
            rising[r] = 0
            spread = (cfg.visual * cfg.reinit_factor) * uniform(rng, (r.size, fish, dim))
            z[r] = book.best_z[r][:, None, :] + spread
            fz[r] = book.evaluate(z[r], r)
            swarm_best[r] = fz[r].min(axis=1)
            book.set_scale(r, schedule()[0][r] / cfg.visual)
    return book.result()
