"""Process-level tuning for the batched numerics.

The swarm's hot loop allocates many short-lived arrays of a few hundred KB. glibc serves
allocations above its mmap threshold (128 KB by default) with fresh mmap()s, so every temporary
costs page faults, and freed heap is trimmed back to the OS eagerly; together that halves the
objective's throughput. :func:`tune_allocator` raises those thresholds with mallopt() -- the same
effect as the MALLOC_MMAP_THRESHOLD_ / MALLOC_TRIM_THRESHOLD_ / MALLOC_TOP_PAD_ environment
variables. It is a no-op on other C libraries and is safe to call more than once.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
_done = False


def tune_allocator(mmap_threshold: int = 32 << 20, trim_threshold: int = 128 << 20) -> bool:
    """Raise glibc's mmap and trim thresholds; returns True when applied."""
    global _done
    if _done:
        return True
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    ok = all(
        mallopt(param, value)
        for param, value in (
            (_M_MMAP_THRESHOLD, mmap_threshold),
            (_M_TRIM_THRESHOLD, trim_threshold),
            (_M_TOP_PAD, mmap_threshold),
        )
    )
    _done = bool(ok)
    return _done
