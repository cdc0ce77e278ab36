"""Lost samples from a time column: a step of about k sample periods means k - 1 were lost.

For formats without a sequence number (text and CSV logs). The period is the median of the
first 1024 time steps (jitter of a fraction of a period rounds away), the same whatever the
chunking; :meth:`GapCounter.push` holds the first samples back until it is known.
"""

from __future__ import annotations

import numpy as np

from .frames import FrameBatch

#: Time steps the period is taken from (as the static detector derives its rate).
PERIOD_PROBE = 1024


class GapCounter:
    """Fills ``lost_before`` of the batches pushed through it (see the module docstring)."""

    def __init__(self) -> None:
        self.period: float | None = None
        self._t_last: float | None = None
        self._held: list[FrameBatch] = []
        self._count = 0

    def push(self, batch: FrameBatch) -> FrameBatch | None:
        """A batch in; the batch ready to go out (None while the first ones are held)."""
        if self.period is None:
            if len(batch):
                self._held.append(batch)
                self._count += len(batch)
            if self._count <= PERIOD_PROBE:
                return None
            return self._release()
        return self._fill(batch)

    def drain(self) -> FrameBatch | None:
        """End of stream: the held batches, even though fewer than the probe."""
        return self._release() if self._held else None

    def _release(self) -> FrameBatch:
        batch = FrameBatch.concat(self._held)
        self._held, self._count = [], 0
        t = batch.time_s[: PERIOD_PROBE + 1]
        self.period = float(np.median(np.diff(t))) if t.shape[0] > 1 else 0.0
        return self._fill(batch)

    def _fill(self, batch: FrameBatch) -> FrameBatch:
        batch.lost_before = self.lost(batch.time_s)
        return batch

    def lost(self, t: np.ndarray) -> np.ndarray:
        """lost_before for the next times (continuing from the previous call)."""
        lost = np.zeros(t.shape[0], dtype=np.int64)
        if t.shape[0] == 0:
            return lost
        prev = t[0] if self._t_last is None else self._t_last
        self._t_last = float(t[-1])
        period = self.period or 0.0
        if not (np.isfinite(period) and period > 0):
            return lost  # the detector reports times that do not increase
        steps = np.diff(t, prepend=prev)
        with np.errstate(invalid="ignore"):
            k = np.rint(steps / period) - 1
        lost[:] = np.where(np.isfinite(k) & (k > 0), k, 0)
        return lost
