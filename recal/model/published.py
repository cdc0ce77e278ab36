"""What makes a published coefficients file self-describing (docs/apply.md#the-published-file).

The daemon's ``coefficients.json`` is read by a navigation computer that has no recal. Beside
the coefficients it carries, from here: its own schema, the model's equations and units, the
reference temperature T0 of the temperature terms, and the temperature the calibration was made
at, so that the file and docs/apply.md are enough to apply it. Pure: dictionaries in and out.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from recal.model.coefficient_schema import DEFAULT_T0_C
from recal.model.terms import catalogue_terms, seed_terms

#: The published file's own schema (the coefficients inside keep recal.coefficients/N).
PUBLISHED_SCHEMA = "recal.published/1"
DOCUMENTATION = "docs/apply.md"

#: The forward model (true input -> output) of each triad, every catalogue effect written out;
#: an effect the file does not carry is zero. ``*`` and ``**2`` act per axis.
EQUATIONS = {
    "gyro": "N_g = K_g * (1 + sT_g (T - T0)) * [ (I + E_g) w + b_g + kT_g (T - T0)"
    " + kdT_g dT/dt + G f + d_g t ]",
    "accel": "N_a = K_a * (1 + sT_a (T - T0)) * [ (I + E_a) f + K2_a * f**2 + a_a * |f| + b_a"
    " + kT_a (T - T0) ]",
    "misalignment": "E = [[0, Exz, Exy], [Eyz, 0, Eyx], [Ezy, Ezx, 0]]",
    "inverse": "accel first: f = (I + E_a)^-1 (N_a / (K_a (1 + sT_a (T - T0))) - b_a - kT_a (T - T0)"
    " - K2_a * f**2 - a_a * |f|), iterated from the linear solution until it no longer changes;"
    " then w = (I + E_g)^-1 (N_g / (K_g (1 + sT_g (T - T0))) - b_g - kT_g (T - T0) - kdT_g dT/dt"
    " - G f - d_g t)",
}
#: The symbol each equation uses for a file's keys.
SYMBOLS = {
    "gyro.scale": "K_g", "gyro.bias": "b_g", "gyro.misalignment": "E_g",
    "accel.scale": "K_a", "accel.bias": "b_a", "accel.misalignment": "E_a",
    "accel.quadratic": "K2_a", "gyro.bias_temperature": "kT_g",
    "gyro.scale_temperature": "sT_g", "gyro.bias_temperature_rate": "kdT_g",
    "gyro.g_sensitivity": "G (row-major: Gxx, Gxy, ..., Gzz)", "gyro.bias_drift": "d_g",
    "accel.bias_temperature": "kT_a", "accel.scale_temperature": "sT_a",
    "accel.scale_asymmetry": "a_a",
}  # fmt: skip
INPUTS = {
    "w": "angular rate of the body relative to inertial space, deg/h",
    "f": "specific force, g (1 g = 9.80665 m/s^2); at rest it points up, |f| = local gravity",
    "N_g, N_a": "the sensor's outputs, in its output units",
    "T": "temperature, degC",
    "dT/dt": "temperature rate, degC/h: the slope over the last 60 s",
    "t": "time since the start of the recording, h",
}


def describe_model(coefficients: Mapping[str, Any]) -> dict[str, Any]:
    """The ``model`` block of a published file for a coefficients block (section 5 layout):
    equations, units of the inputs and of every key the block carries, T0."""
    units = {t.name: t.units for s in ("gyro", "accel") for t in seed_terms(s)}
    units.update({name: t.units for name, t in catalogue_terms().items()})
    carried = [f"{s}.{k}" for s in ("gyro", "accel") for k in (coefficients.get(s) or {})]
    carried += list(coefficients.get("effects") or {})
    t0 = coefficients.get("t0_c", DEFAULT_T0_C)
    return {
        "documentation": DOCUMENTATION,
        "equations": dict(EQUATIONS),
        "inputs": dict(INPUTS),
        "units": {
            name: {"symbol": SYMBOLS.get(name, name), "unit": _unit_text(units.get(name))}
            for name in carried
        },
        "vector_order": "x, y, z",
        "reference_temperature_c": t0,
    }


def _unit_text(unit: Any) -> str:
    if unit is None:
        return "see the plugin that defines it (metadata.plugins)"
    return unit if isinstance(unit, str) else ", ".join(unit)


def calibration_temperature(temperature_c: np.ndarray | None) -> dict[str, float] | None:
    """Mean, min and max of the windows' temperatures a calibration used, degC (None when the
    positions carry no temperature): the range over which coefficients without temperature
    terms hold, and where temperature terms were fitted."""
    if temperature_c is None:
        return None
    t = np.asarray(temperature_c, dtype=float)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return None
    return {"mean": float(t.mean()), "min": float(t.min()), "max": float(t.max())}


def published_metadata(coefficients: Mapping[str, Any] | None) -> dict[str, Any]:
    """The keys a published file adds beside its coefficients: ``schema``, ``model`` and
    ``calibration_temperature_c`` (from the block's metadata; null when unknown)."""
    block = coefficients or {}
    meta = block.get("metadata") or {}
    return {
        "schema": PUBLISHED_SCHEMA,
        "model": describe_model(block),
        "calibration_temperature_c": meta.get("calibration_temperature_c"),
    }
