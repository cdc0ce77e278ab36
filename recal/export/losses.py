"""What a format cannot carry, and what leaving it out costs in the format's own units.

Every export (docs/export.md) states, in the file or beside it, each term of the calibration it
drops with the largest error that dropping it makes at a stated input: a format without
misalignment gets ``||E||`` times a reference input, one without the quadratic term ``K2 (1 g)^2``,
one without temperature terms their size per degC, and so on. The reference inputs are 1 g for
an accelerometer and one of the format's own rate units for a gyro.

Also the shared pieces of every exporter: the unit factors and the ``(I + E)`` matrix.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from recal.model.coefficients import CoefficientSet
from recal.model.reference import G0_M_S2
from recal.model.terms import MISALIGNMENT_INDEX

#: Rate units a format may use: factor from deg/h (the model's gyro input unit).
RATE_FROM_DEG_H = {"rad/s": math.radians(1.0) / 3600.0, "deg/s": 1.0 / 3600.0, "deg/h": 1.0}
#: Specific-force units: factor from g (9.80665 m/s^2, the model's accel input unit).
FORCE_FROM_G = {"m/s^2": G0_M_S2, "g": 1.0}


@dataclass(frozen=True)
class Loss:
    """One term a format cannot carry: ``residual`` (in ``unit``) is the largest error that
    leaving it out makes ``at`` the stated input (``None`` when it cannot be said)."""

    term: str
    residual: float | None
    unit: str
    at: str

    def line(self) -> str:
        size = "unknown" if self.residual is None else f"{self.residual:.3g} {self.unit}"
        return f"{self.term}: not carried; leaving it out costs up to {size} {self.at}"


def one_plus_e(coefficients: CoefficientSet, sensor: str) -> np.ndarray:
    """I + E of a triad (docs/apply.md), from the set's six misalignment values (0 if absent)."""
    A = np.eye(3)
    mis = coefficients.get(f"{sensor}.misalignment")
    if mis is not None:
        for (r, c), v in zip(MISALIGNMENT_INDEX, mis, strict=True):
            A[r, c] = v
    return A


def _largest(values: np.ndarray | None) -> float:
    return 0.0 if values is None else float(np.max(np.abs(values)))


def losses(
    coefficients: CoefficientSet,
    dropped: Iterable[str],
    rate_unit: str = "rad/s",
    force_unit: str = "m/s^2",
) -> list[Loss]:
    """A :class:`Loss` for each term of ``dropped`` the set carries with a nonzero value.

    ``gyro.scale`` in ``dropped`` means a format whose gyro has no scale factor: it reads the
    raw output as if it were already in ``rate_unit``."""
    r = RATE_FROM_DEG_H[rate_unit]
    f = FORCE_FROM_G[force_unit]
    at_rate = f"at 1 {rate_unit}"
    out: list[Loss] = []
    for name in dropped:
        value = coefficients.get(name)
        if value is None or not np.any(value):
            continue
        if name == "gyro.scale":
            # the raw output taken as rate_unit: 1 rate_unit of input reads K / (1 / r) of it
            ratio = np.abs(value * (1.0 / r) - 1.0)
            if ratio.max() <= 1e-9:  # already rad/s (or deg/s) to float32 precision and beyond
                continue
            out.append(
                Loss(name, float(ratio.max()), rate_unit, f"{at_rate} (raw read as {rate_unit})")
            )
        elif name.endswith(".misalignment"):
            norm = float(
                np.linalg.norm(one_plus_e(coefficients, name.split(".")[0]) - np.eye(3), 2)
            )
            if name.startswith("gyro"):
                out.append(Loss(name, norm, rate_unit, at_rate))
            else:
                out.append(Loss(name, norm * f, force_unit, "at 1 g"))
        elif name == "accel.quadratic":
            out.append(
                Loss(name, _largest(value) * f, force_unit, "at 1 g along an axis (x4 at 2 g)")
            )
        elif name == "accel.scale_asymmetry":
            out.append(Loss(name, _largest(value) * f, force_unit, "at 1 g"))
        elif name == "accel.bias_temperature":
            out.append(Loss(name, _largest(value) * f, f"{force_unit}/degC", "per degC from T0"))
        elif name == "accel.scale_temperature":
            out.append(
                Loss(name, _largest(value) * f, f"{force_unit}/degC", "at 1 g, per degC from T0")
            )
        elif name == "gyro.bias_temperature":
            out.append(Loss(name, _largest(value) * r, f"{rate_unit}/degC", "per degC from T0"))
        elif name == "gyro.scale_temperature":
            out.append(
                Loss(name, _largest(value), f"{rate_unit}/degC", f"{at_rate}, per degC from T0")
            )
        elif name == "gyro.bias_temperature_rate":
            out.append(
                Loss(
                    name,
                    _largest(value) * r,
                    f"{rate_unit}/(degC/h)",
                    "per degC/h of temperature rate",
                )
            )
        elif name == "gyro.g_sensitivity":
            G = np.asarray(value, float).reshape(3, 3)
            out.append(Loss(name, float(np.linalg.norm(G, 2)) * r, rate_unit, "at 1 g"))
        elif name == "gyro.bias_drift":
            out.append(
                Loss(name, _largest(value) * r, f"{rate_unit}/h", "per hour from the session start")
            )
        else:
            out.append(Loss(name, None, "", "(an effect this exporter does not know)"))
    return out


def carried_terms(coefficients: CoefficientSet) -> list[str]:
    """Every term the set carries, in a stable order (seed terms first)."""
    seed = [
        f"{s}.{k}"
        for s in ("gyro", "accel")
        for k in ("scale", "bias", "misalignment", "quadratic")
    ]
    names = [n for n in seed if n in coefficients.values]
    return names + sorted(n for n in coefficients.values if n not in seed)
