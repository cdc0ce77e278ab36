"""A user effect for ``recal diagnose --plugin`` / ``recal calibrate --plugin --effects``.

Accelerometer warm-up: a bias that drifts linearly over the session, b_a,i += d_i t (t in hours
from the session's start). The catalogue has this for the gyro (``gyro.bias_drift``) but not for
the accelerometer. On imucal's Ferraris session `recal diagnose` reports the accelerometer-norm
residual falling with time (r = -0.66) and asks for a plugin; this is it. Its typical size is a
MEMS accelerometer's during the first minutes after power-on (tens of mg per hour).
"""

from recal import ColumnBiasTerm

TERMS = [
    ColumnBiasTerm(
        "accel.bias_drift",
        "accel",
        ("dx", "dy", "dz"),
        "g/h",
        (5e-2, 5e-2, 5e-2),
        (0.0, 0.0, 0.0),
        "Accelerometer bias drifts linearly over the session (warm-up after power-on).",
        needs=frozenset({"time_h"}),
        column="time_h",
    )
]
