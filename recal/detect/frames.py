"""The frames a detector is fed: time, gyro and accel checked as float arrays, and the slice of
frames processed per internal step.
"""

from __future__ import annotations

import numpy as np

from recal.errors import RecalInputError

#: Frames processed per internal step: bounds the temporaries however much is fed at once.
SLICE_FRAMES = 1 << 16


def frame_arrays(time_s, gyro, accel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time (N,) in s, gyro (N, 3), accel (N, 3)) as float64 arrays; RecalInputError when the
    triads do not have one row of three per time."""
    t = np.asarray(time_s, dtype=np.float64).reshape(-1)
    n = t.shape[0]
    g = np.asarray(gyro, dtype=np.float64)
    a = np.asarray(accel, dtype=np.float64)
    if g.shape != (n, 3) or a.shape != (n, 3):
        raise RecalInputError(
            f"gyro and accel must have shape ({n}, 3) like time_s; got {g.shape} and {a.shape}"
        )
    return t, g, a
