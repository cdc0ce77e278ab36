"""Novel artificial fish swarm algorithm, NAFSA (seed 000 section 2.3; seed 002 section 4).

One iteration of every live Monte Carlo run, all fish at once:

1. **Individual behaviour** (prey + free move). Up to ``tries`` times each fish samples
   ``X_j = X_i + Visual * U(-1, 1)`` (per-dimension Visual vector) and moves there when
   ``f(X_j) <= f(X_i)`` (eq. 6). A fish that found nothing better after all tries moves at random,
   ``X_i + Visual * U(-1, 1)``, and keeps that position even if it is worse (eq. 7); this keeps the
   swarm diverse, while the best is kept separately (see below).
2. **Group behaviour** (replaces swarm and follow). ``X_Center`` is the mean of the run's fish. A
   fish with ``f(X_Center) < f(X_i)`` moves toward the centre,
   ``X_i + (X_Center - X_i) / Dis_{i,Center} * Visual * U(0, 1)`` (eq. 8); otherwise toward the
   best, ``X_i + (X_Best - X_i) / Dis_{i,Best} * Visual * U(0, 1)`` (eq. 9).
   ``X_Best = X_Center`` whenever ``f(X_Center) < f(X_Best)`` (eq. 10).
3. **Visual update** ``Visual(t+1) = Visual(t) * CF`` (eq. 5) with
   ``CF = CF_min + (CF_max - CF_min) * U(0, 1)`` (eq. 4); see ``cf_mode``.

NAFSA has no Step, no crowd factor delta and no separate *bulletin*: the best position X_Best is
the best point ever evaluated by the run (updated from every evaluation, which includes eq. 10), so
the best-so-far never gets worse. Each dimension is measured in units of the initial Visual vector
(see :mod:`recal.solve.swarm`); ``Dis`` is the Euclidean distance in those units. CF is one scalar per
run and iteration, so Visual keeps the shape of the Visual vector of seed 000 Table 1.

Evaluations per fish and iteration: between 2 and ``tries + 2`` (prey tries that are still
pending, the free move of unsuccessful fish, the group move) plus one per run for ``X_Center``;
about 3.6 with the defaults.

Benchmark behind the adaptive defaults: ``sum((x - x*)^2)``, ``x*`` uniform within +-1 of the
centre per dimension, Visual = 2 per dimension, 50 fish, 100 seeded runs; median (90th percentile)
of ``|x_best - x*|`` after 20 / 40 / 60 / 100 iterations:

=====  ==================  =================  =================  =================
D      20                  40                 60                 100
=====  ==================  =================  =================  =================
3      8.5e-4 (2.1e-3)     2.2e-6 (7.1e-6)    1.2e-8 (3.6e-8)    1e-12
6      2.7e-2 (4.2e-2)     1.0e-3 (1.7e-3)    4.2e-5 (7.4e-5)    1.2e-7
9      0.16 (0.22)         1.9e-2 (2.7e-2)    2.2e-3 (3.0e-3)    2.9e-5
12     0.44 (0.55)         7.9e-2 (0.10)      1.7e-2 (2.2e-2)    6.3e-4
15     0.77 (0.97)         0.21 (0.27)        6.5e-2 (8.1e-2)    5.2e-3
=====  ==================  =================  =================  =================

After 60 iterations ``f / f_0`` (best over initial best) has median 1e-6 (D = 9), 4e-5
(D = 12), 4e-4 (D = 15). ``cf_mode="literal"`` stalls by iteration ~20 at
``|x - x*|`` = 0.03 (D = 3), 1.1 (D = 9), 1.6 (D = 12); ``"constant"`` (CF = 0.9) reaches
2.7e-4 (D = 3), 4.6e-3 (D = 9), 1.4e-2 (D = 12) at 60 but does not adapt to the problem's scale.
A grid over ``(cf_min, cf_max)`` in {(0.2, 0.6), (0.3, 0.8), (0.5, 0.9)}, ``cf_success`` in
{0.85, 0.9, 0.95, 1} and ``visual_floor`` in {0, 0.3, 0.5, 0.7} on sphere (D = 3-15), rank-deficient
(half the eigenvalues 0) and rotated ill-conditioned quadratics put (0.3, 0.8), 0.9, 0.5 among
the best (the top settings differ by less than the run-to-run noise). The floor matters most:
without it these CF values freeze most runs (D = 12: median ``f / f_0`` 3e-2 instead of 4e-5), and
the best floor-less setting, (0.5, 0.9) with ``cf_success = 1``, still leaves a bad tail (90th
percentile 3e-3 at D = 12, 3e-2 at D = 15). NAFSA searches isotropically in units of the Visual
vector, so ill-conditioning slows it: a rotated D = 6 quadratic with condition 1e3 only gets to
``f / f_0`` ~ 2e-3 in 60 iterations; polish with LM.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recal.solve.swarm import (
    Objective,
    SwarmBook,
    SwarmConfig,
    SwarmResult,
    distances,
    median_fish,
    move_toward,
    swarm_mean,
    uniform,
)

CF_MODES = ("adaptive", "literal", "constant")

#: (CF_min, CF_max) of seed 000 Table 1, used by ``cf_mode="literal"``.
LITERAL_CF = (0.000001, 0.999999)
#: Default (CF_min, CF_max) of ``cf_mode="adaptive"`` (benchmarked, see ``NafsaConfig``).
ADAPTIVE_CF = (0.3, 0.8)
#: Default CF of ``cf_mode="constant"``.
CONSTANT_CF = 0.9


@dataclass(frozen=True)
class NafsaConfig(SwarmConfig):
    """NAFSA settings; defaults as seed 000 Table 1 (50 fish, 60 iterations) except ``cf_mode``.

    Attributes:
        cf_mode: how the Contraction Factor CF shrinks Visual (eqs. 4-5):

            * ``"adaptive"`` (default): CF as a function of the run's progress (the paper allows
              CF to be "a constant or a function"). In an iteration where the run's best-so-far
              did not improve, ``Visual *= CF`` with CF drawn by eq. 4 in ``[cf_min, cf_max]``
              (default ``ADAPTIVE_CF = (0.3, 0.8)``); after an improving iteration
              ``Visual *= cf_success`` (default 0.9; values > 1 expand, capped at the initial
              Visual). A contraction never takes Visual below ``visual_floor`` (0.5) times the
              run's swarm spread, ``median_i Dis(X_i, X_Best) / sqrt(D)``: eqs. 8-9 move a fish
              by at most Visual, so when Visual shrinks faster than the swarm gathers, the fish
              left behind are stranded and the run freezes early (milder form of the literal
              mode's failure). The floor is what removes the bad tail; see the module notes for
              the benchmark behind these defaults.
            * ``"literal"``: eq. 4 with Table 1's ``CF_min = 1e-6``, ``CF_max = 0.999999``, applied
              every iteration and cumulatively (eq. 5). Since ``E[ln CF] = -1`` (ln of a uniform
              variate), Visual shrinks by about ``e^-1`` per iteration: after 15 iterations it is
              ~3e-7 of its start, after 20 ~2e-9, and the swarm is frozen; later iterations no
              longer change the best. Kept to reproduce the papers.
            * ``"constant"``: ``Visual *= cf_max`` every iteration (default ``CONSTANT_CF``).

        cf_min, cf_max: bounds of eq. 4; ``None`` selects the mode's default.
        cf_success: adaptive mode only, factor applied to Visual after an iteration that
            improved the run's best (capped at the initial Visual).
        visual_floor: adaptive mode only, a contraction stops at ``visual_floor`` times the
            swarm spread (0 disables the floor).
    """

    cf_mode: str = "adaptive"
    cf_min: float | None = None
    cf_max: float | None = None
    cf_success: float = 0.9
    visual_floor: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.cf_mode not in CF_MODES:
            raise ValueError(f"cf_mode must be one of {CF_MODES}, got {self.cf_mode!r}")
        lo, hi = self.cf_bounds
        if not (0.0 < lo <= hi < 1.0 or (self.cf_mode == "constant" and 0.0 < hi <= 1.0)):
            raise ValueError(f"need 0 < cf_min <= cf_max < 1, got ({lo!r}, {hi!r})")
        if not self.cf_success > 0.0:
            raise ValueError(f"cf_success must be > 0, got {self.cf_success!r}")
        if not self.visual_floor >= 0.0:
            raise ValueError(f"visual_floor must be >= 0, got {self.visual_floor!r}")

    @property
    def cf_bounds(self) -> tuple[float, float]:
        """``(CF_min, CF_max)`` after resolving the mode defaults."""
        if self.cf_mode == "literal":
            lo, hi = LITERAL_CF
        elif self.cf_mode == "adaptive":
            lo, hi = ADAPTIVE_CF
        else:
            lo = hi = CONSTANT_CF
        hi = hi if self.cf_max is None else float(self.cf_max)
        lo = (hi if self.cf_mode == "constant" else lo) if self.cf_min is None else self.cf_min
        return float(lo), float(hi)


def nafsa(
    objective: Objective,
    center: np.ndarray,
    visual: np.ndarray,
    rng: np.random.Generator,
    config: NafsaConfig | None = None,
    *,
    with_runs: bool = False,
) -> SwarmResult:
    """Minimise ``objective`` with NAFSA from ``R`` batched, independent Monte Carlo runs.

    Args:
        objective: ``X (P, D) -> f (P,)``, lower is better; nan counts as +inf.
        center: ``(D,)`` or ``(R, D)`` preset coefficients each run's swarm starts around.
        visual: ``(D,)`` or ``(R, D)`` initial per-dimension Visual vector (seed 000 Table 1). The
            initial swarm is ``center + visual * U(-1, 1)``.
        rng: the only source of randomness; the same seed gives the same result.
        config: :class:`NafsaConfig`.
        with_runs: call ``objective(X, run)`` with the (P,) run index of every row, for
            objectives that differ between runs (see :mod:`recal.solve.swarm`).

    Returns:
        :class:`recal.solve.swarm.SwarmResult`; ``visual_history`` holds Visual(t) / Visual(0).
    """
    cfg = NafsaConfig() if config is None else config
    book = SwarmBook(objective, center, visual, cfg, with_runs)
    runs, dim, fish = book.runs, book.dim, cfg.fish
    cf_lo, cf_hi = cfg.cf_bounds

    z = uniform(rng, (runs, fish, dim))
    fz = book.evaluate(z, np.arange(runs))
    scale = np.ones(runs)  # Visual(t) / Visual(0), one scalar per run
    book.record(scale)

    while book.active.any():
        idx = book.active_runs()
        every = idx.size == runs  # all runs live: their arrays as they are, no gather or scatter
        zi, fi, si = (z, fz, scale) if every else (z[idx], fz[idx], scale[idx])
        best_before = book.best_f[idx].copy()
        zi, fi = _individual_behaviour(book, rng, idx, zi, fi, si, cfg.tries)
        zi, fi = _group_behaviour(book, rng, idx, zi, fi, si)
        cf = cf_lo + (cf_hi - cf_lo) * uniform(rng, (idx.size,), 0.0)  # eq. 4
        if cfg.cf_mode == "adaptive":
            improved = book.best_f[idx] < best_before
            spread = median_fish(distances(zi, book.best_z.take(idx, axis=0))) / np.sqrt(dim)
            floor = np.minimum(cfg.visual_floor * spread, si)
            si = np.where(improved, np.minimum(si * cfg.cf_success, 1.0), si * cf)
            si = np.maximum(si, floor)
        else:
            si = si * cf  # eq. 5
        if every:  # the behaviours returned new arrays: nothing above changed z, fz, scale
            z, fz, scale = zi, fi, si
        else:
            z[idx], fz[idx], scale[idx] = zi, fi, si
        book.record(scale)
    return book.result()


def _individual_behaviour(
    book: SwarmBook,
    rng: np.random.Generator,
    runs: np.ndarray,
    z: np.ndarray,
    fz: np.ndarray,
    scale: np.ndarray,
    tries: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Prey (eq. 6, up to ``tries`` attempts) then free move (eq. 7) for all fish of ``runs``."""
    vis = scale[:, None, None]
    pending = np.ones(fz.shape, dtype=bool)
    z, fz = z.copy(), fz.copy()
    for _ in range(tries):
        zj = uniform(rng, z.shape)
        zj *= vis
        zj += z  # X_j = X_i + Visual * U(-1, 1)
        fj = book.evaluate(zj, runs, pending)
        ok = pending & (fj <= fz)  # eq. 6: move when f(X_i) >= f(X_j)
        _move(z, zj, ok)
        np.copyto(fz, fj, where=ok)
        pending &= ~ok
        if not pending.any():
            return z, fz
    zf = uniform(rng, z.shape)
    zf *= vis
    zf += z  # eq. 7: X_i + Visual * U(-1, 1), accepted even if worse
    ff = book.evaluate(zf, runs, pending)
    _move(z, zf, pending)
    np.copyto(fz, ff, where=pending)
    return z, fz


def _move(z: np.ndarray, to: np.ndarray, which: np.ndarray) -> None:
    """``z[which] = to[which]`` in place for fish ``which`` (n, F) of ``z`` (n, F, D): row
    indices, about twice as fast as a mask broadcast over D."""
    if not (z.flags.c_contiguous and to.flags.c_contiguous):  # reshape would copy
        np.copyto(z, to, where=which[..., None])
        return
    rows = np.flatnonzero(which)
    d = z.shape[-1]
    z.reshape(-1, d)[rows] = to.reshape(-1, d).take(rows, axis=0)


def _group_behaviour(
    book: SwarmBook,
    rng: np.random.Generator,
    runs: np.ndarray,
    z: np.ndarray,
    fz: np.ndarray,
    scale: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Move toward X_Center (eq. 8) or X_Best (eq. 9); X_Best takes X_Center if better (eq. 10)."""
    center = swarm_mean(z)[:, None, :]  # X_Center, (n, 1, D)
    f_center = book.evaluate(center, runs)  # the bulletin update applies eq. 10
    toward_center = f_center < fz  # (n, F)
    target = np.where(toward_center[..., None], center, book.best_z.take(runs, axis=0)[:, None, :])
    length = uniform(rng, z.shape, 0.0)
    length *= scale[:, None, None]  # Visual * Rand(0, 1), per dimension
    z = move_toward(z, target, length)
    return z, book.evaluate(z, runs)
