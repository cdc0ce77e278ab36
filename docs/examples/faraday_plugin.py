"""A user effect for ``recal diagnose --plugin`` / ``recal calibrate --plugin --effects``.

FOG magnetic (Faraday) sensitivity: a bias proportional to the Earth's magnetic field along each
axis, b_g,i += F_i B_i, with B the field in body axes. The field is fixed in the local frame
(north, east, up components in gauss at the site), so per position it is
B = B_N north + B_E east + B_U gravity_direction, from the attitude-free context the engine
provides (recal.model.plugins): no attitude is needed.
"""

from dataclasses import dataclass

import numpy as np

from recal import Term

#: Earth field at a mid-latitude northern site, gauss (north, east, up): 0.20 G horizontal,
#: 0.45 G pointing down.
FIELD_NEU_GAUSS = (0.20, 0.0, -0.45)


@dataclass(frozen=True)
class FaradayBias(Term):
    field_neu: tuple[float, float, float] = FIELD_NEU_GAUSS

    def offset(self, p, ctx):
        bn, be, bu = self.field_neu
        B = bn * ctx["north"] + be * ctx["east"] + bu * ctx["gravity_direction"]  # (M, 3)
        return p[:, None, :] * np.asarray(B)[None]


TERMS = [
    FaradayBias(
        "gyro.faraday",
        "gyro",
        ("Fx", "Fy", "Fz"),
        "deg/h/gauss",
        (0.02, 0.02, 0.02),
        (0.0, 0.0, 0.0),
        "Bias proportional to the magnetic field along the axis (Faraday effect in the coil).",
        needs=frozenset({"north", "east", "gravity_direction"}),
    )
]
