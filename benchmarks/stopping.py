"""Benchmarks that start daemons stop them when they are interrupted or time out.

``timeout`` and a CI job's cancel send SIGTERM, which by default ends Python at once: no
``finally`` runs, and a daemon the benchmark started (``recal serve``, ``recal fleet serve``,
each in its own session so that a kill -9 of it is one ``killpg``) is left running, orphaned.
``stop_on_sigterm()`` turns SIGTERM into ``KeyboardInterrupt``, so the benchmark's ``finally``
blocks stop its daemons and drop its databases as after Ctrl-C
(tests/test_benchmark_interrupt.py).
"""

from __future__ import annotations

import signal
from types import FrameType


def _interrupt(_signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def stop_on_sigterm() -> None:
    """SIGTERM raises ``KeyboardInterrupt`` in the main thread (call it from ``main``)."""
    signal.signal(signal.SIGTERM, _interrupt)
