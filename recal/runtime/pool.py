"""Independent batches of work, in this process or in forked worker processes.

The Monte Carlo runs of a swarm (:mod:`recal.solve.mcs`) are split into batches that share
nothing but their inputs. With more than one worker, this process is one of them and the others
are forked: the batch function reaches them through ``fork`` (inherited, never pickled: its
inputs are large arrays and closures), every worker uses one BLAS thread (the matrices are tiny;
an inherited BLAS pool oversubscribes the cores and can spin), and the forked workers' progress
reaches the caller through a shared counter polled whenever this process reports its own. One
worker runs the batches here, with the same one-thread BLAS.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, wait
from typing import Any, TypeVar

T = TypeVar("T")
Progress = Callable[[float], None]
#: A batch: ``fn(batch_index, progress)``; ``progress(units)`` reports work done (or is None).
Batch = Callable[[int, Progress | None], T]

#: How often the caller reads the workers' progress counter, s.
PROGRESS_POLL_S = 0.25

_FORKED: tuple[Batch, Any] | None = None  # set in the caller just before forking the workers


def default_workers(n_batches: int) -> int:
    """One worker per core this process may use, at most one per batch; 1 without ``fork``."""
    if "fork" not in mp.get_all_start_methods():
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(n_batches, cores or 1))


def run_batches(
    fn: Batch, n_batches: int, workers: int | None = None, progress: Progress | None = None
) -> list[Any]:
    """``[fn(b, ...) for b in range(n_batches)]``, in ``workers`` processes (None: one per
    core), in batch order; ``progress`` gets the units the batches report as they go.

    This process is one of the workers: it runs every ``workers``-th batch itself while
    ``workers - 1`` forked processes run the others, so a swarm's two batches on two cores
    fork once, and one of them runs where its inputs are already in memory (about 25 ms of a
    0.35 s MCS-NAFSA)."""
    global _FORKED
    workers = default_workers(n_batches) if workers is None else max(1, min(workers, n_batches))
    from threadpoolctl import threadpool_limits

    if workers == 1:
        # the workers' one-thread BLAS here too (restored on return)
        with threadpool_limits(1, user_api="blas"):
            return [fn(b, progress) for b in range(n_batches)]
    ctx = mp.get_context("fork")
    counter = ctx.Value("d", 0.0) if progress else None  # inherited by the forked workers
    _FORKED = (fn, counter)
    here = set(range(0, n_batches, workers))
    reported = 0.0

    def poll() -> None:
        """Pass on what the forked workers counted since the last poll."""
        nonlocal reported
        if progress and counter is not None and counter.value > reported:
            value = counter.value
            progress(value - reported)
            reported = value

    def report(units: float) -> None:  # this process's batches, and the workers' meanwhile
        assert progress is not None
        progress(units)
        poll()

    try:
        with ProcessPoolExecutor(
            max_workers=workers - 1, mp_context=ctx, initializer=_init_worker
        ) as pool:
            futures = {b: pool.submit(_run_forked, b) for b in range(n_batches) if b not in here}
            with threadpool_limits(1, user_api="blas"):
                done = {b: fn(b, report if progress else None) for b in sorted(here)}
            pending = set(futures.values())
            while pending:
                _, pending = wait(pending, timeout=PROGRESS_POLL_S)
                poll()
            return [done[b] if b in here else futures[b].result() for b in range(n_batches)]
    finally:
        _FORKED = None


def _init_worker() -> None:
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def _run_forked(b: int) -> Any:
    assert _FORKED is not None
    fn, counter = _FORKED

    def report(units: float) -> None:
        with counter.get_lock():
            counter.value += units

    return fn(b, None if counter is None else report)
