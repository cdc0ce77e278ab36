"""Independent batches of work, in this process or in forked worker processes.

The Monte Carlo runs of a swarm (:mod:`recal.solve.mcs`) are split into batches that share
nothing but their inputs. With more than one worker, the batch function reaches the workers
through ``fork`` (inherited, never pickled: its inputs are large arrays and closures), each
worker uses one BLAS thread (the matrices are tiny; an inherited BLAS pool oversubscribes the
cores and can spin), and the workers' progress reaches the caller through a shared counter the
caller polls. One worker runs the batches here, with the same one-thread BLAS.
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
    core), in batch order; ``progress`` gets the units the batches report as they go."""
    global _FORKED
    workers = default_workers(n_batches) if workers is None else max(1, min(workers, n_batches))
    if workers == 1:
        from threadpoolctl import threadpool_limits  # 70 ms to import: only on this path

        # the workers' one-thread BLAS here too (restored on return)
        with threadpool_limits(1, user_api="blas"):
            return [fn(b, progress) for b in range(n_batches)]
    ctx = mp.get_context("fork")
    counter = ctx.Value("d", 0.0) if progress else None  # inherited by the forked workers
    _FORKED = (fn, counter)
    try:
        with ProcessPoolExecutor(
            max_workers=workers, mp_context=ctx, initializer=_init_worker
        ) as pool:
            futures = [pool.submit(_run_forked, b) for b in range(n_batches)]
            pending, reported = set(futures), 0.0
            while pending:
                _, pending = wait(pending, timeout=PROGRESS_POLL_S)
                if progress and counter is not None and counter.value > reported:
                    progress(counter.value - reported)
                    reported = counter.value
            return [fut.result() for fut in futures]
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
