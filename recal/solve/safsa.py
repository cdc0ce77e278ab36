"""Standard artificial fish swarm algorithm, SAFSA (Li Xiaolei 2002; seed 002 section 2, seed 000
section 2.1), the baseline NAFSA is compared with.

Parameters (seed 000 section 2.1): a scalar *Visual* (sight field) and *Step* (largest move), the
crowd factor delta (``0 < delta < 1``), ``try_number`` and a *bulletin* holding the best fish.
Visual and Step are measured in the normalised coordinates ``z = (x - center) / visual`` of
:mod:`recal.solve.swarm`, so ``Visual = 1`` corresponds to the per-dimension Visual vector passed in;
``Dis_{i,j} = |X_i - X_j|`` is Euclidean in those coordinates. ``n_f`` is the number of other fish
within Visual of a fish, ``F`` the number of fish.

One iteration, for every fish of every live run at once:

* **Swarm** (seed 002 section 2.2.2): ``X_c`` is the centre of the fish within Visual. If
  ``f(X_c) < f(X_i)`` and ``n_f / F < delta`` (not crowded), the fish moves
  ``X_i + (X_c - X_i) / Dis * Step * Rand()``.
* **Follow** (section 2.2.3): ``X_j`` is the best fish within Visual. If ``f(X_j) < f(X_i)`` and
  ``X_j``'s own neighbourhood is not crowded (``n_f(j) / F < delta``), the fish moves
  ``X_i + (X_j - X_i) / Dis * Step * Rand()``.
* If swarm or follow applies, the fish takes whichever of the two results is better; otherwise it
  **preys** (section 2.2.1): up to ``try_number`` points ``X_j = X_i + Visual * U(-1, 1)``; at the
  first one with ``f(X_j) < f(X_i)`` it moves ``X_i + (X_j - X_i) / Dis * Step * Rand()``; if none is
  better it makes a **free move** ``X_i + Step * U(-1, 1)`` (section 2.2.4).
* Every move is accepted, better or not; the **bulletin** (best-so-far, X_Best) is updated from
  every evaluated point, so it never gets worse.

Evaluations per fish and iteration: up to ``3 + try_number`` (centre, swarm move, follow move, or
the prey tries and the prey/free move). Pairwise distances use ``(R, F, F)`` arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recal.solve.swarm import Objective, SwarmBook, SwarmConfig, SwarmResult, move_toward, uniform


@dataclass(frozen=True)
class SafsaConfig(SwarmConfig):
    """SAFSA settings (normalised units: Visual = 1 is the Visual vector passed in).

    Attributes:
        visual: Visual, the sight field (default 1.0).
        step: Step, the largest move (default 0.5).
        delta: crowd factor delta; a neighbourhood is crowded when ``n_f / F >= delta``
            (default 0.618).
    """

    visual: float = 1.0
    step: float = 0.5
    delta: float = 0.618

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (self.visual > 0 and self.step > 0):
            raise ValueError("visual and step must be > 0")
        if not 0.0 < self.delta <= 1.0:
            raise ValueError(f"delta must be in (0, 1], got {self.delta!r}")


def safsa(
    objective: Objective,
    center: np.ndarray,
    visual: np.ndarray,
    rng: np.random.Generator,
    config: SafsaConfig | None = None,
    *,
    with_runs: bool = False,
) -> SwarmResult:
    """Minimise ``objective`` with the standard AFSA from ``R`` batched, independent runs.

    Args:
        objective: ``X (P, D) -> f (P,)``, lower is better; nan counts as +inf.
        center: ``(D,)`` or ``(R, D)`` preset coefficients each run's swarm starts around.
        visual: ``(D,)`` or ``(R, D)`` per-dimension scale; the initial swarm is
            ``center + visual * U(-1, 1)`` and ``config.visual``/``config.step`` are in its units.
        rng: the only source of randomness; the same seed gives the same result.
        config: :class:`SafsaConfig`.
        with_runs: call ``objective(X, run)`` with the (P,) run index of every row, for
            objectives that differ between runs (see :mod:`recal.solve.swarm`).
    """
    cfg = SafsaConfig() if config is None else config
    book = SwarmBook(objective, center, visual, cfg, with_runs)
    runs = book.runs
    z = uniform(rng, (runs, cfg.fish, book.dim))
    fz = book.evaluate(z, np.arange(runs))
    ones = np.ones(runs)
    book.record(ones)
    vis = np.full(runs, cfg.visual)
    step = np.full(runs, cfg.step)
    while book.active.any():
        idx = book.active_runs()
        z[idx], fz[idx] = afsa_iteration(
            book, rng, idx, z[idx], fz[idx], vis[idx], step[idx], cfg.delta, cfg.tries
        )
        book.record(ones)
    return book.result()


def afsa_iteration(
    book: SwarmBook,
    rng: np.random.Generator,
    runs: np.ndarray,
    z: np.ndarray,
    fz: np.ndarray,
    visual: np.ndarray,
    step: np.ndarray,
    delta: float,
    tries: int,
) -> tuple[np.ndarray, np.ndarray]:
    """One SAFSA iteration (swarm, follow, else prey/free move) for all fish of ``runs``.

    ``z`` (n, F, D) and ``fz`` (n, F) are the runs' fish; ``visual`` and ``step`` (n,) the per-run
    Visual and Step (OAFSA varies them). Returns the new positions and objective values.
    """
    n, fish, _ = z.shape
    vis = visual[:, None]
    stp = step[:, None]
    # Neighbourhoods: Dis_{i,j} < Visual, excluding the fish itself.
    sq = np.einsum("nfd,nfd->nf", z, z)
    d2 = z @ z.transpose(0, 2, 1)
    d2 *= -2.0
    d2 += sq[:, :, None]
    d2 += sq[:, None, :]
    near = d2 < (visual * visual)[:, None, None]
    eye = np.eye(fish, dtype=bool)
    near &= ~eye
    n_f = near.sum(axis=2)  # (n, F)
    has = n_f > 0
    uncrowded = n_f < delta * fish  # n_f / F < delta

    # Swarm behaviour: toward the centre X_c of the neighbours.
    zc = near.astype(float) @ z
    zc /= np.maximum(n_f, 1)[:, :, None]
    f_c = book.evaluate(zc, runs, has & uncrowded)
    swarm_ok = has & uncrowded & (f_c < fz)
    z_sw = move_toward(z, zc, stp[..., None] * uniform(rng, (n, fish, 1), 0.0))
    f_sw = book.evaluate(z_sw, runs, swarm_ok)

    # Follow behaviour: toward the best neighbour X_j when its neighbourhood is not crowded.
    f_near = np.where(near, fz[:, None, :], np.inf)
    lead = np.argmin(f_near, axis=2)  # (n, F)
    f_lead = np.take_along_axis(f_near, lead[..., None], axis=2)[..., 0]
    lead_uncrowded = np.take_along_axis(uncrowded, lead, axis=1)
    follow_ok = has & lead_uncrowded & (f_lead < fz)
    z_lead = np.take_along_axis(z, lead[..., None], axis=1)
    z_fo = move_toward(z, z_lead, stp[..., None] * uniform(rng, (n, fish, 1), 0.0))
    f_fo = book.evaluate(z_fo, runs, follow_ok)

    # The better of the two social moves (f is +inf where a behaviour did not apply).
    use_fo = f_fo < f_sw
    social = swarm_ok | follow_ok
    z_new = np.where(use_fo[..., None], z_fo, z_sw)
    f_new = np.minimum(f_fo, f_sw)

    # Prey (try_number tries within Visual), else free move, for the remaining fish.
    prey = ~social
    if prey.any():
        pending = prey.copy()
        target = z.copy()
        for _ in range(tries):
            zj = uniform(rng, z.shape)
            zj *= vis[..., None]
            zj += z
            fj = book.evaluate(zj, runs, pending)
            found = pending & (fj < fz)
            np.copyto(target, zj, where=found[..., None])
            pending &= ~found
            if not pending.any():
                break
        z_pr = move_toward(z, target, stp[..., None] * uniform(rng, (n, fish, 1), 0.0))
        free = uniform(rng, z.shape)
        free *= stp[..., None]
        free += z  # free move: X_i + Step * U(-1, 1)
        np.copyto(z_pr, free, where=pending[..., None])
        f_pr = book.evaluate(z_pr, runs, prey)
        np.copyto(z_new, z_pr, where=prey[..., None])
        np.copyto(f_new, f_pr, where=prey)
    return z_new, f_new
