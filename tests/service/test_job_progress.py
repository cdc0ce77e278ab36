"""A running job's progress: what its worker reports reaches JobRunner.progress (and /health)."""

from __future__ import annotations

import threading
import time

from service.jobs import JobEnd, JobRunner, report_progress


def _counting(steps: int, pause_s: float) -> int:
    """A job that reports ``steps`` units done, one every ``pause_s``."""
    for k in range(1, steps + 1):
        time.sleep(pause_s)
        report_progress(k, steps)
    return steps


def test_a_running_job_shows_its_elapsed_time_and_units_done() -> None:
    runner = JobRunner(timeout_s=60)
    ended = threading.Event()
    ends: list[JobEnd] = []
    try:
        runner.submit(_counting, (8, 0.3), lambda end: (ends.append(end), ended.set()))
        seen = []
        deadline = time.monotonic() + 30
        while not ended.is_set() and time.monotonic() < deadline:
            p = runner.progress()
            if p is not None and p["done"] is not None:
                seen.append(p)
            time.sleep(0.05)
        assert ended.wait(30) and ends[0].ok and ends[0].result == 8
        # several reports while it ran (at most one per 0.5 s), increasing, out of 8
        dones = [p["done"] for p in seen]
        assert len(set(dones)) >= 2 and dones == sorted(dones) and max(dones) <= 8
        assert all(p["total"] == 8 and p["timeout_s"] == 60 for p in seen)
        assert seen[-1]["elapsed_s"] > seen[0]["elapsed_s"] >= 0
        assert runner.progress() is None  # nothing runs any more
    finally:
        runner.shutdown()


def test_report_progress_outside_a_worker_does_nothing() -> None:
    report_progress(1, 2)  # no supervisor pipe in this process: silently ignored
