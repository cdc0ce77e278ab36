"""The static detector's noise floor for one device, kept in the store (:class:`FloorKeeper`)."""

from __future__ import annotations

import logging
from collections import deque
from typing import Any

import numpy as np

from recal.detect.floor import NoiseFloor
from recal.detect.windows import Window
from service.events import Events
from service.store.errors import StoreError

log = logging.getLogger("recal.pipeline")

#: Windows between two refinements of the stored noise floor, and how many recent windows the
#: refined value is the median of.
REFINE_EVERY, REFINE_OVER = 10, 50
#: One refinement moves the floor by at most this factor (a few odd windows cannot run away).
REFINE_MAX_STEP = 2.0


class FloorKeeper:
    """The static detector's noise floor for one device, kept in the store.

    A unit restarted at sea may be moving: thresholds learned then would let motion through as
    "static". So the floor learned once (from the quietest stretches of the first minutes, or an
    initial still period) is stored with the device and reused at every start, and refined only
    from windows that passed the detector: the median of their moving-variance traces.
    """

    def __init__(self, store: Any, device: str, events: Events, window_samples: int) -> None:
        self._store = store
        self.device = device
        self._events = events
        self._w = window_samples
        self._recent: deque[tuple[float, float]] = deque(maxlen=REFINE_OVER)
        self._since = 0
        self._windows = 0
        self.floor: NoiseFloor | None = None

    def load(self) -> NoiseFloor | None:
        """The stored floor for this device and moving-window length, or None."""
        row = self._store.noise_floor(self.device)
        if row is None or int(row["window_samples"]) != self._w:
            return None
        self._windows = int(row["windows"])
        self.floor = NoiseFloor(
            accel=row["accel"],
            gyro=row["gyro"],
            window_samples=self._w,
            source=f"stored for this device on {row['created_at'][:19]} ({row['source']})",
        )
        return self.floor

    def save(self, floor: NoiseFloor, source: str) -> None:
        self.floor = floor
        try:
            self._store.save_noise_floor(self.device, {
                "accel": floor.accel, "gyro": floor.gyro, "window_samples": floor.window_samples,
                "source": source, "windows": self._windows})  # fmt: skip
        except StoreError as exc:  # kept in memory; the next refinement stores it again
            log.warning("event=noise_floor cannot store it: %s", exc)
            return
        self._events.emit("noise_floor", f"detector noise floor {source}: accel "
                          f"{floor.accel:.4g}, gyro {floor.gyro:.4g}",
                          {"device": self.device, "windows": self._windows})  # fmt: skip

    def refine(self, windows: list[Window]) -> None:
        """Take the moving-variance traces of windows that passed; store a new floor now and
        then."""
        for w in windows:
            # an accelerometer-only window's gyro trace is tremor, not the gyro's noise floor
            if np.isfinite(w.accel_mvar) and np.isfinite(w.gyro_mvar) and w.gyro_still:
                self._recent.append((w.accel_mvar, w.gyro_mvar))
                self._since += 1
                self._windows += 1
        if self.floor is None or self._since < REFINE_EVERY:
            return
        self._since = 0
        med = np.median(np.array(self._recent), axis=0)
        old = np.array([self.floor.accel, self.floor.gyro])
        new = np.clip(med, old / REFINE_MAX_STEP, old * REFINE_MAX_STEP)
        floor = NoiseFloor(float(new[0]), float(new[1]), self._w, self.floor.source)
        self.save(floor, f"refined from {self._windows} windows that passed")
