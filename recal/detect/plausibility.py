"""Unit plausibility of a device that outputs physical units (a KVH: gyro deg/h, accel g).

At rest the gyro triad's mean output has the norm of Earth's rate (15.04 deg/h) and the
accelerometer's the norm of gravity (~1 g), whatever the orientation, up to the calibration
errors (a few per cent at worst for a FOG unit in service). A norm off by a large factor is not
a calibration: it is a wrong setting. The gyro norm scales with the assumed frame rate when the
unit sends delta angles (rate = delta x frames per second), so the ratio also names the rate the
recording most likely had. Pure numerics; the callers phrase the setting's name.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H

#: Output rates a KVH 1750/1775/DSP-1760 can be set to (Hz), for the suggestion.
KVH_RATES_HZ = (1.0, 10.0, 25.0, 50.0, 100.0, 200.0, 250.0, 500.0, 1000.0, 2000.0, 5000.0)
#: A triad whose median norm at rest is off by more than this factor is implausible.
MAX_FACTOR = 1.5


@dataclass(frozen=True)
class UnitCheck:
    """Median norm at rest over the windows against its reference (ratio 1 = plausible)."""

    gyro_ratio: float | None  # median |gyro| / Earth rate
    accel_ratio: float | None  # median |accel| / 1 g

    @property
    def gyro_implausible(self) -> bool:
        return self.gyro_ratio is not None and not _near_one(self.gyro_ratio)

    @property
    def accel_implausible(self) -> bool:
        return self.accel_ratio is not None and not _near_one(self.accel_ratio)

    def suggested_rate_hz(self, rate_hz: float) -> float | None:
        """The KVH rate that would make the gyro read Earth's rate (delta-angle output)."""
        if self.gyro_ratio is None or self.gyro_ratio <= 0 or rate_hz <= 0:
            return None
        want = rate_hz / self.gyro_ratio
        return min(KVH_RATES_HZ, key=lambda r: abs(np.log(r / want)))

    def problems(self, rate_setting: str, rate_hz: float, unit_settings: str) -> list[str]:
        """One sentence per implausible triad, naming the settings to check."""
        out = []
        if self.gyro_implausible:
            assert self.gyro_ratio is not None
            suggest = self.suggested_rate_hz(rate_hz)
            hint = "" if suggest is None else f" (these windows suggest {suggest:g} Hz)"
            out.append(
                f"at rest the gyro reads {self.gyro_ratio * OMEGA_IE_DEG_H:.3g} deg/h where "
                f"Earth's rate is {OMEGA_IE_DEG_H:.2f} deg/h ({self.gyro_ratio:.3g}x): the unit "
                f"outputs physical units, so a setting is wrong: {rate_setting} {rate_hz:g}{hint}, "
                f"or {unit_settings}"
            )
        if self.accel_implausible:
            assert self.accel_ratio is not None
            out.append(
                f"at rest the accelerometers read {self.accel_ratio:.3g} g where gravity is "
                f"about 1 g: the unit outputs physical units, so its accel setting is wrong"
            )
        return out


def _near_one(ratio: float) -> bool:
    return 1.0 / MAX_FACTOR <= ratio <= MAX_FACTOR


def check_units(positions: Positions) -> UnitCheck:
    """Median norms of the windows' mean gyro (deg/h) and accel (g) outputs, as ratios."""
    gyro = accel = None
    if positions.has_gyro and len(positions):
        gyro = float(np.median(np.linalg.norm(positions.gyro, axis=1))) / OMEGA_IE_DEG_H
    if positions.has_accel and len(positions):
        accel = float(np.median(np.linalg.norm(positions.accel, axis=1)))
    return UnitCheck(gyro, accel)
