"""A user effect for ``recal diagnose --plugin`` / ``recal calibrate --plugin --effects``.

Accelerometer cross-coupling: each axis responds to the product of the two specific-force
components across it, a_x += k_x f_y f_z, a_y += k_y f_z f_x, a_z += k_z f_x f_y (k in g/g^2,
f the specific force in g). A pendulous accelerometer shows it when the proof mass's pivot is
loaded by the cross-axis forces; datasheets quote it as a cross-coupling coefficient of some
ug/g^2 to about 100 ug/g^2. The catalogue's quadratic term (K2 f_i^2 on the same axis) cannot
express it: a product of two other axes is odd in each of them.

At rest it shows mainly in the accelerometer norm, which sees (k_x + k_y + k_z) f_x f_y f_z;
the dot product with the gyro sees each k weighted by Earth rate, far below the gyro noise. So
static positions pin down the sum well and each k only weakly.
"""

from dataclasses import dataclass

import numpy as np

from recal import Term


@dataclass(frozen=True)
class CrossCoupling(Term):
    def nonlinear(self, p, x, ctx):
        # x: true specific force (P, M, 3) in g; the products across each axis, cyclic (y z, z x, x y)
        across = np.roll(x, -1, axis=-1) * np.roll(x, -2, axis=-1)
        return p[:, None, :] * across


TERMS = [
    CrossCoupling(
        "accel.cross_coupling",
        "accel",
        ("kx", "ky", "kz"),
        "g/g^2",
        (3e-5, 3e-5, 3e-5),
        (0.0, 0.0, 0.0),
        "Each axis responds to the product of the two specific-force components across it.",
    )
]
