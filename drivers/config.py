"""Decoder configuration: the device settings that change how raw fields map to physical units."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import DriverInputError

_RAD_TO_DEG = 180.0 / math.pi
_PER_S_TO_PER_H = 3600.0


@dataclass(frozen=True)
class DecoderConfig:
    """How the device is set up (KVH ROTFMT, ROTUNITS, TEMPUNITS, DR).

    gyro_output: "delta" (angle per sample, the device default) or "rate" (per second).
    gyro_units: "rad" (default) or "deg".
    temperature_units: "degC" (default) or "centi" (hundredths of a degC, the device's C_100).
    rate_hz: data rate, 1-5000 Hz (default 1000); turns delta angles into rates and sequence
    numbers into time when the frame carries no timestamp.
    """

    gyro_output: str = "delta"
    gyro_units: str = "rad"
    temperature_units: str = "degC"
    rate_hz: float = 1000.0

    def __post_init__(self) -> None:
        if self.gyro_output not in ("delta", "rate"):
            raise DriverInputError(
                f"gyro output must be 'delta' or 'rate', not {self.gyro_output!r}"
            )
        if self.gyro_units not in ("rad", "deg"):
            raise DriverInputError(f"gyro units must be 'rad' or 'deg', not {self.gyro_units!r}")
        if self.temperature_units not in ("degC", "centi"):
            raise DriverInputError(
                f"temperature units must be 'degC' or 'centi', not {self.temperature_units!r}"
            )
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 100_000):
            raise DriverInputError(f"data rate must be a positive number of Hz, not {self.rate_hz}")

    @property
    def gyro_to_dph(self) -> float:
        """Factor from the raw gyro field to a rate in deg/h."""
        per_second = self.rate_hz if self.gyro_output == "delta" else 1.0
        to_deg = _RAD_TO_DEG if self.gyro_units == "rad" else 1.0
        return per_second * to_deg * _PER_S_TO_PER_H

    @property
    def temperature_scale(self) -> float:
        """Factor from the raw temperature field to degC."""
        return 0.01 if self.temperature_units == "centi" else 1.0


DEFAULT_CONFIG = DecoderConfig()


def physical_to_raw_gyro(
    gyro_dph: np.ndarray, config: DecoderConfig = DEFAULT_CONFIG
) -> np.ndarray:
    """deg/h -> the device's raw gyro field as configured (e.g. delta angle in rad per sample)."""
    return np.asarray(gyro_dph, dtype=np.float64) / config.gyro_to_dph


def raw_to_physical_gyro(
    gyro_raw: np.ndarray, config: DecoderConfig = DEFAULT_CONFIG
) -> np.ndarray:
    """The device's raw gyro field -> deg/h (the inverse of physical_to_raw_gyro)."""
    return np.asarray(gyro_raw, dtype=np.float64) * config.gyro_to_dph


def physical_to_raw_temperature(
    temperature_c: np.ndarray, config: DecoderConfig = DEFAULT_CONFIG
) -> np.ndarray:
    """degC -> the raw temperature field value (whole degC or hundredths), not yet rounded."""
    return np.asarray(temperature_c, dtype=np.float64) / config.temperature_scale
