"""Shared pieces of the artificial-fish-swarm optimisers (NAFSA, SAFSA, OAFSA).

Conventions common to :func:`recal.solve.nafsa.nafsa`, :func:`recal.solve.safsa.safsa` and
:func:`recal.solve.oafsa.oafsa`:

* **Objective.** ``objective(X)`` maps a batch ``X`` of shape ``(P, D)`` to ``f`` of shape
  ``(P,)``; *lower is better* (the swarms minimise the indicator of seed 000 eq. 14). ``inf`` and
  ``nan`` mark invalid points; ``nan`` is treated as ``+inf``. Every behaviour step evaluates its
  whole batch (all fish of all live Monte Carlo runs) in one call, so the objective should be
  vectorised over the rows of ``X``. Rows are grouped by run in increasing run order, but a batch
  does **not** hold the same number of rows per run (prey tries only evaluate the fish still
  trying, a batch of centres has one row per run, terminated runs drop out). An objective that
  depends on the run (e.g. each Monte Carlo run has its own base coefficients) is passed with
  ``with_runs=True`` and is then called as ``objective(X, run)``, ``run`` being the ``(P,)``
  integer run index (0 .. R-1) of every row.
* **Monte Carlo runs in a batch.** ``R`` independent runs advance together: state arrays have shape
  ``(R, F, D)`` for ``F`` fish. Run ``r`` only ever sees its own centre, Visual, fish and best
  (X_Best / *bulletin*). The runs share one random stream, so run ``r``'s trajectory depends on
  ``R`` (a run computed with ``R = 1`` differs from the same run inside ``R = 5``); for a fixed
  ``R`` and seed every result is bit-for-bit reproducible. Runs that have terminated are not
  evaluated any more.
* **Initial swarm.** ``X = center + visual * U(-1, 1)`` per fish and dimension: the papers start
  around the preset (prior) coefficients with the per-dimension Visual of seed 000 Table 1.
* **Normalised coordinates.** Internally every optimiser works in ``z = (x - center) / visual``, so
  that the Visual vector passed in is the unit box. Distances (``Dis`` in seed 000 eqs. 8-9, the
  neighbourhoods of SAFSA) are Euclidean in ``z``; for an isotropic Visual this is the papers'
  Euclidean distance up to a constant, and it keeps the algorithms independent of parameter units
  when, as in Table 1, the Visual components span several decades.
* **Best-so-far (bulletin / X_Best).** Updated from *every* evaluated point, so the history of the
  best-so-far objective is non-increasing and the best is never lost (seed 000 section 2.3.2).
* **Termination** (seed 000 section 3.2): a run stops when its best-so-far is below
  ``threshold`` (``"threshold"``), when over the last ``stall_iterations`` iterations its
  best-so-far improved by no more than ``stall_tol`` relative (``"stall"``), or after
  ``iterations`` iterations (``"max_iterations"``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Objective = Callable[..., np.ndarray]
"""``X (P, D) -> f (P,)``, lower is better; ``inf``/``nan`` for invalid points (``nan`` -> ``+inf``).

With ``with_runs=True`` the solvers call it as ``objective(X, run)`` with ``run`` (P,) the run
index of each row."""

STOP_THRESHOLD = "threshold"
STOP_STALL = "stall"
STOP_MAX_ITERATIONS = "max_iterations"


@dataclass(frozen=True)
class SwarmConfig:
    """Settings common to all three fish swarms.

    Attributes:
        fish: number of artificial fishes F per run (seed 000 Table 1: 50).
        iterations: maximum number of iterations per run (seed 000 Table 1: 60).
        tries: ``try_number``, the number of prey attempts per fish and iteration.
        threshold: indicator threshold (seed 000 section 3.3.2 uses sigma < 1e-8). A run stops as
            soon as its best-so-far objective is ``< threshold``. ``threshold <= 0`` (the default
            0.0) switches the test off, which suits non-negative indicators.
        stall_iterations: stop a run when its best-so-far improved by no more than
            ``stall_tol * |f_old|`` over the last ``stall_iterations`` iterations (seed 000 section
            3.2, third condition). 0 (default) switches the test off.
        stall_tol: relative improvement tolerance of the stall test.
    """

    fish: int = 50
    iterations: int = 60
    tries: int = 3
    threshold: float = 0.0
    stall_iterations: int = 0
    stall_tol: float = 1e-6

    def __post_init__(self) -> None:
        if int(self.fish) != self.fish or self.fish < 1:
            raise ValueError(f"fish must be a positive integer, got {self.fish!r}")
        if int(self.iterations) != self.iterations or self.iterations < 0:
            raise ValueError(f"iterations must be a non-negative integer, got {self.iterations!r}")
        if int(self.tries) != self.tries or self.tries < 1:
            raise ValueError(f"tries must be a positive integer, got {self.tries!r}")
        if int(self.stall_iterations) != self.stall_iterations or self.stall_iterations < 0:
            raise ValueError(
                f"stall_iterations must be a non-negative integer, got {self.stall_iterations!r}"
            )
        if not self.stall_tol >= 0.0:
            raise ValueError(f"stall_tol must be >= 0, got {self.stall_tol!r}")
        if np.isnan(self.threshold):
            raise ValueError("threshold must not be nan")


@dataclass(frozen=True)
class SwarmResult:
    """Outcome of ``R`` batched Monte Carlo runs of one fish swarm.

    Attributes:
        best_x: ``(R, D)`` best-so-far position (X_Best, the *bulletin*) per run.
        best_f: ``(R,)`` its objective value.
        history: ``(R, n + 1)`` best-so-far objective after initialisation and after each of the
            ``n = iterations.max()`` iterations; non-increasing per run. A run that stopped early
            repeats its final value.
        evaluations: total number of points evaluated (sum of all objective batch sizes).
        iterations: ``(R,)`` iterations each run performed before it terminated.
        stop_reason: per run, ``"threshold"``, ``"stall"`` or ``"max_iterations"``.
        visual_history: ``(R, n + 1)`` Visual relative to its initial value, as set after
            initialisation and after each iteration, i.e. the Visual the next iteration uses
            (NAFSA: Visual(t) / Visual(0), the cumulative product of CF of eq. 5; OAFSA:
            ``Visual_G / Visual`` of eq. 1, including restarts; SAFSA: 1). Diagnostic only.
    """

    best_x: np.ndarray
    best_f: np.ndarray
    history: np.ndarray
    evaluations: int
    iterations: np.ndarray
    stop_reason: list[str]
    visual_history: np.ndarray | None = None


def prepare_problem(center: np.ndarray, visual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Broadcast ``center`` ((D,) or (R, D)) and ``visual`` ((D,) or (R, D)) to two (R, D) arrays.

    Raises ``ValueError`` for non-finite input, negative Visual or mismatched shapes.
    """
    c = np.atleast_2d(np.asarray(center, dtype=float))
    v = np.atleast_2d(np.asarray(visual, dtype=float))
    if c.ndim != 2 or v.ndim != 2:
        raise ValueError("center and visual must have shape (D,) or (R, D)")
    try:
        shape = np.broadcast_shapes(c.shape, v.shape)
    except ValueError as exc:
        raise ValueError(
            f"center {c.shape} and visual {v.shape} do not broadcast to (R, D)"
        ) from exc
    if shape[1] < 1:
        raise ValueError("the search space needs at least one dimension")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(v))):
        raise ValueError("center and visual must be finite")
    if np.any(v < 0):
        raise ValueError("visual must be non-negative")
    return np.array(np.broadcast_to(c, shape)), np.array(np.broadcast_to(v, shape))


class SwarmBook:
    """Bookkeeping shared by the optimisers: evaluation, bulletin, history and termination.

    Positions are handled in normalised coordinates ``z = (x - center) / visual``. ``evaluate``
    maps them to parameter space, calls the objective once for the whole batch, replaces nan by
    +inf, counts the evaluations and updates the best-so-far (X_Best, *bulletin*) of every run
    involved, so the best can never get worse.
    """

    def __init__(
        self,
        objective: Objective,
        center: np.ndarray,
        visual: np.ndarray,
        config: SwarmConfig,
        with_runs: bool = False,
    ) -> None:
        self.objective = objective
        self.with_runs = with_runs
        self.center, self.visual = prepare_problem(center, visual)
        self.config = config
        self.runs, self.dim = self.center.shape
        self.best_z = np.zeros((self.runs, self.dim))
        self.best_f = np.full(self.runs, np.inf)
        self.evaluations = 0
        self.active = np.ones(self.runs, dtype=bool)
        self.iterations = np.zeros(self.runs, dtype=int)
        self.stop_reason = np.full(self.runs, "", dtype=object)
        self._history: list[np.ndarray] = []
        self._scales: list[np.ndarray] = []
        self.iteration = 0
        self._tiles: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._offset = bool(self.center.any())  # searches about the origin skip the add

    # -- evaluation ------------------------------------------------------------------------------
    def evaluate(
        self, z: np.ndarray, runs: np.ndarray, mask: np.ndarray | None = None
    ) -> np.ndarray:
        """Objective of normalised points ``z`` (n, K, D) belonging to run indices ``runs`` (n,).

        With ``mask`` (n, K) only the selected points are evaluated; the others get ``+inf``.
        Returns ``(n, K)``. Updates the best-so-far of the runs from every evaluated point.
        """
        n, k, _ = z.shape
        x = self._to_parameters(z, runs).reshape(n * k, self.dim)
        picked = None if mask is None else np.flatnonzero(mask)  # rows in mask order
        if picked is not None:
            x = x.take(picked, axis=0)  # take: several times faster than a boolean index
        p = x.shape[0]
        if p == 0:
            return np.full((n, k), np.inf)
        if self.with_runs:
            owner = np.repeat(runs, k) if picked is None else runs.take(picked // k)
            fx = np.array(self.objective(x, owner), dtype=float)
        else:
            fx = np.array(self.objective(x), dtype=float)  # a private copy, nan replaced below
        if fx.shape != (p,):
            raise ValueError(f"objective returned shape {fx.shape}, expected ({p},)")
        fx[np.isnan(fx)] = np.inf
        self.evaluations += p
        if picked is None:
            f = fx.reshape(n, k)
        else:
            f = np.full(n * k, np.inf)
            f[picked] = fx
            f = f.reshape(n, k)
        # Bulletin: best of this batch per run, kept only if strictly better than the stored best.
        j = np.argmin(f, axis=1)
        fj = f[np.arange(n), j]
        better = fj < self.best_f[runs]
        if np.any(better):
            rb = runs[better]
            self.best_f[rb] = fj[better]
            self.best_z[rb] = z[np.nonzero(better)[0], j[better]]
        return f

    def _to_parameters(self, z: np.ndarray, runs: np.ndarray) -> np.ndarray:
        """``x = center + visual * z`` for ``z`` (n, K, D) of runs ``runs``, as (n, K, D).

        Uses ``center`` and ``visual`` tiled to (R, K * D), because a broadcast over a short last
        axis is several times slower than a flat elementwise operation.
        """
        n, k, d = z.shape
        if k == 1:
            x = z * self.visual[runs][:, None, :]
            x += self.center[runs][:, None, :]
            return x
        tiles = self._tiles.get(k)
        if tiles is None:
            tiles = (np.tile(self.visual, (1, k)), np.tile(self.center, (1, k)))
            self._tiles[k] = tiles
        vt, ct = tiles
        if n != self.runs:  # runs are sorted and unique, so n == R means all runs
            vt, ct = vt.take(runs, axis=0), ct.take(runs, axis=0)
        x = z.reshape(n, k * d) * vt
        if self._offset:
            x += ct
        return x.reshape(n, k, d)

    def best_x(self) -> np.ndarray:
        """Best-so-far positions in parameter space, (R, D)."""
        return self.center + self.best_z * self.visual

    # -- termination -----------------------------------------------------------------------------
    def active_runs(self) -> np.ndarray:
        """Indices of the runs that have not terminated."""
        return np.flatnonzero(self.active)

    def record(self, scale: np.ndarray | None = None) -> None:
        """Close the initialisation (first call) or one iteration: history and termination tests.

        ``scale`` (R,) is the Visual scale, relative to the initial Visual, that the next
        iteration will use (diagnostic).
        """
        cfg = self.config
        if self._history:
            self.iteration += 1
            self.iterations[self.active] += 1
        self._history.append(self.best_f.copy())
        self._scales.append(np.ones(self.runs) if scale is None else np.array(scale, dtype=float))
        t = self.iteration
        stop = np.zeros(self.runs, dtype=bool)
        reason = np.full(self.runs, "", dtype=object)
        if cfg.threshold > 0:
            hit = self.active & (self.best_f < cfg.threshold)
            reason[hit] = STOP_THRESHOLD
            stop |= hit
        if cfg.stall_iterations > 0 and t >= cfg.stall_iterations:
            old = self._history[t - cfg.stall_iterations]
            with np.errstate(invalid="ignore"):  # inf - inf: no progress
                progress = old - self.best_f > cfg.stall_tol * np.abs(old)
            progress |= np.isposinf(old) & (self.best_f < old)  # first finite value
            stalled = ~progress
            stalled &= self.active & ~stop
            reason[stalled] = STOP_STALL
            stop |= stalled
        if t >= cfg.iterations:
            last = self.active & ~stop
            reason[last] = STOP_MAX_ITERATIONS
            stop |= last
        self.stop_reason[stop] = reason[stop]
        self.active &= ~stop

    def set_scale(self, runs: np.ndarray, scale: np.ndarray) -> None:
        """Overwrite the latest recorded Visual scale of ``runs`` (after a restart, OAFSA)."""
        self._scales[-1][runs] = scale

    def result(self) -> SwarmResult:
        """Freeze the bookkeeping into a :class:`SwarmResult`."""
        return SwarmResult(
            best_x=self.best_x(),
            best_f=self.best_f.copy(),
            history=np.stack(self._history, axis=1),
            evaluations=int(self.evaluations),
            iterations=self.iterations.copy(),
            stop_reason=self.stop_reason.tolist(),
            visual_history=np.stack(self._scales, axis=1),
        )


def uniform(rng: np.random.Generator, shape: tuple[int, ...], low: float = -1.0) -> np.ndarray:
    """``U(low, 1)`` samples (``low`` is -1 or 0), drawn as ``rng.random`` and shifted in place."""
    u = rng.random(shape)
    if low == -1.0:
        u *= 2.0
        u -= 1.0
    elif low != 0.0:
        raise ValueError("low must be -1 or 0")
    return u


def move_toward(z: np.ndarray, target: np.ndarray, length: np.ndarray) -> np.ndarray:
    """``z + (target - z) / Dis * length`` with ``Dis = |target - z|`` (Euclidean, normalised).

    ``length`` broadcasts against ``z`` (a scalar per fish, or per dimension as in seed 000 eqs.
    8-9). Fish already at the target (``Dis = 0``) stay where they are. Written with in-place
    operations: this is on the hot path.
    """
    step = target - z
    dis = np.sqrt(np.einsum("...d,...d->...", step, step))[..., None]
    dis[dis == 0.0] = np.inf
    step /= dis
    step *= length
    step += z
    return step


def distances(z: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Euclidean distances ``|z_i - point|`` of fish ``z`` (n, F, D) to ``point`` (n, D) -> (n, F)."""
    d = z - point[:, None, :]
    return np.sqrt(np.einsum("nfd,nfd->nf", d, d))


def swarm_mean(z: np.ndarray) -> np.ndarray:
    """Mean over the fish axis of ``z`` (n, F, D) -> (n, D) (a matmul: faster than ``mean``)."""
    return np.full(z.shape[1], 1.0 / z.shape[1]) @ z


def median_fish(values: np.ndarray) -> np.ndarray:
    """Median-like order statistic (the ``F // 2``-th smallest) over the last axis of (n, F)."""
    k = values.shape[-1] // 2
    return np.partition(values, k, axis=-1)[..., k]
