"""A static window: the means, spreads and noise statistics of one still period, and the
positions-table columns of a list of them (docs/reference.md#positions)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from recal.detect.noise import pooled_standard_errors
from recal.model.positions import (
    ACCEL_COLUMNS,
    ACCEL_SEM_COLUMNS,
    ACCEL_STD_COLUMNS,
    GYRO_COLUMNS,
    GYRO_SEM_COLUMNS,
    GYRO_STD_COLUMNS,
)

#: Columns beyond docs/reference.md#positions that :func:`windows_to_columns` adds.
#: ``gyro_still``: 1 where both triads were still, 0 for an accelerometer-only window (the gyro
#: static invariants leave that row out; see recal.solve.problem).
#: ``gyro_vertical`` (hull windows without the ship's heading): 0 where the rate along gravity is
#: no measurement (heading creep, recal.detect.creep); ``creep_dph``: the heading rate, deg/h.
EXTRA_COLUMNS = ("frames_lost", "frames_invalid", "gyro_still", "gyro_vertical", "creep_dph")


@dataclass(frozen=True, eq=False)
class Window:
    """One static window. Means and standard deviations in input units, shape (3,).

    start_s / end_s: times of the first and last frame averaged, from the session start (the
    first frame fed). start_index / end_index: their frame indices (inclusive). samples: frames
    averaged (valid ones). std: per-sample standard deviation (ddof 1). temperature_c: mean of the
    finite temperatures (NaN without any); temperature_rate_c_per_h: least-squares slope over
    time (NaN with fewer than two). frames_lost / frames_invalid: tolerated holes inside.
    gyro_sem / accel_sem: standard error of the mean, input units, correlated noise included,
    from this window's samples alone (:func:`pooled_standard_errors` pools a recording's
    windows for a steadier value). accel_mvar / gyro_mvar: mean moving-variance trace over the
    window's frames, (input units)^2 (what still data of this unit reads: a noise floor).
    block_frames, allan_sq, allan_terms: the window's Allan statistics over blocks of
    ``block_frames`` frames (row j: averaging over 2^j blocks; 6 columns gyro x y z, accel x y z):
    the sums of half the squared differences of overlapping block averages and their count.
    """

    start_s: float
    end_s: float
    start_index: int
    end_index: int
    samples: int
    gyro: np.ndarray
    accel: np.ndarray
    gyro_std: np.ndarray
    accel_std: np.ndarray
    temperature_c: float
    temperature_rate_c_per_h: float
    frames_lost: int
    frames_invalid: int
    gyro_sem: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    accel_sem: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    accel_mvar: float = math.nan
    gyro_mvar: float = math.nan
    block_frames: int = 0
    allan_sq: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    allan_terms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: False for an accelerometer-only window: the accel was still, the gyro was not (tremor).
    #: Its gyro mean is still a fair rest reference for the slews, not a static gyro reading.
    gyro_still: bool = True
    #: True for a quasi-static window of a moving hull (recal.detect.hull): its means are the
    #: motion-corrected estimates and its sems already carry the motion's residual, so they are
    #: used as they are, not pooled from Allan statistics (it has none).
    quasi_static: bool = False
    #: False where the window's rate along gravity is no measurement: a hull's heading creep,
    #: unknown without the ship's heading, sits in it like a bias (recal.detect.creep); the fit
    #: then uses the rate across gravity only (recal.solve.problem)
    gyro_vertical: bool = True
    #: the hull's heading rate over the window, deg/h clockwise (measured from the ship's
    #: heading where gyro_vertical, else estimated from the vertical excess); NaN: not known
    creep_dph: float = math.nan

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


def windows_to_columns(windows: Sequence[Window]) -> dict[str, np.ndarray]:
    """Positions-table columns (docs/reference.md#positions) plus :data:`EXTRA_COLUMNS`.

    The ``*_sem`` columns are :func:`pooled_standard_errors` over these windows; the gyro's are
    pooled separately over the accelerometer-only windows (``gyro_still`` 0), whose gyro noise
    is the hand's tremor, not the sensor's. The temperature columns appear only when every
    window has a finite value.
    """
    cols: dict[str, np.ndarray] = {
        "start_s": np.array([w.start_s for w in windows], dtype=float),
        "end_s": np.array([w.end_s for w in windows], dtype=float),
        "samples": np.array([w.samples for w in windows], dtype=float),
    }
    quasi = np.array([w.quasi_static for w in windows], dtype=bool)
    gyro_sem = np.array([w.gyro_sem for w in windows], dtype=float).reshape(-1, 3)
    accel_sem = np.array([w.accel_sem for w in windows], dtype=float).reshape(-1, 3)
    if (~quasi).any():
        pooled = [windows[i] for i in np.flatnonzero(~quasi)]
        gyro_sem[~quasi], accel_sem[~quasi] = pooled_standard_errors(pooled)
    still = np.array([w.gyro_still for w in windows], dtype=bool)
    if still[~quasi].any() and not still[~quasi].all():
        for group in (still & ~quasi, ~still & ~quasi):
            idx = np.flatnonzero(group)
            gyro_sem[idx] = pooled_standard_errors([windows[i] for i in idx])[0]
    for names, values in (
        (GYRO_COLUMNS, [w.gyro for w in windows]),
        (ACCEL_COLUMNS, [w.accel for w in windows]),
        (GYRO_STD_COLUMNS, [w.gyro_std for w in windows]),
        (ACCEL_STD_COLUMNS, [w.accel_std for w in windows]),
        (GYRO_SEM_COLUMNS, gyro_sem),
        (ACCEL_SEM_COLUMNS, accel_sem),
    ):
        stack = np.array(values, dtype=float).reshape(-1, 3)
        for j, name in enumerate(names):
            cols[name] = stack[:, j]
    for name in ("temperature_c", "temperature_rate_c_per_h"):
        values = np.array([getattr(w, name) for w in windows], dtype=float)
        if values.size and np.isfinite(values).all():
            cols[name] = values
    cols["frames_lost"] = np.array([w.frames_lost for w in windows], dtype=float)
    cols["frames_invalid"] = np.array([w.frames_invalid for w in windows], dtype=float)
    cols["gyro_still"] = still.astype(float)
    vertical = np.array([w.gyro_vertical for w in windows], dtype=bool)
    if not vertical.all():  # only where some window's vertical rate is no measurement
        cols["gyro_vertical"] = vertical.astype(float)
    creep = np.array([w.creep_dph for w in windows], dtype=float)
    if np.isfinite(creep).any():
        cols["creep_dph"] = creep
    return cols
