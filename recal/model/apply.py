"""Applying a coefficient set: raw outputs -> calibrated angular rates and specific forces.

The error models (docs/reference.md#models) say what a triad outputs for a true input:

    N_g = diag(K_g) [ (I + E_g) w + b_g ]                  w in deg/h
    N_a = diag(K_a) [ (I + E_a) f + K2_a * f**2 + b_a ]    f in g (9.80665 m/s^2)

with the catalogue effects (temperature, temperature rate, g-sensitivity, drift, scale
asymmetry) adding to K, b or the nonlinear part. Applying inverts them, sample by sample:
``x = (I + E)^-1 (N / K_eff - b_eff - h(x))``, where ``h`` is the accelerometer's quadratic
(and asymmetry) term. ``h`` depends on the unknown ``x``, so the inverse starts from the linear
solution and iterates; every sample is then checked against the forward model and refined
until the outputs it predicts match the raw outputs to float64 resolution (docs/apply.md gives
the same steps for a navigation computer in any language).

:func:`apply` is the one-shot, vectorised function (``recal.apply``); :class:`Applier` does the
same on a recording fed in chunks (``recal apply``), keeping the little state that spans chunks:
the time origin of a drift term and the last minute of temperature for a temperature-rate term.
Pure numerics, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet, read_coefficients
from recal.model.error_model import Model, ParameterLayout, inv3
from recal.model.reference import G0_M_S2
from recal.model.terms import MISALIGNMENT_INDEX, Term, catalogue_terms

__all__ = [
    "ACCEL_UNITS",
    "GYRO_UNITS",
    "Applier",
    "Calibrated",
    "apply",
    "triad_models",
]

#: Calibrated-rate units: factor from deg/h (the model's input unit) to the unit.
GYRO_UNITS: dict[str, float] = {
    "deg/h": 1.0,
    "deg/s": 1.0 / 3600.0,
    "rad/s": math.radians(1.0) / 3600.0,
}
#: Specific-force units: factor from g (9.80665 m/s^2, the model's input unit) to the unit.
ACCEL_UNITS: dict[str, float] = {"g": 1.0, "m/s^2": G0_M_S2}
#: dT/dt for a temperature-rate term: the slope over the last minute (a navigation computer
#: applying in real time has no later samples; a whole-degree thermometer needs the span).
TEMPERATURE_RATE_SPAN_S = 60.0
#: Refinement steps after the inverse's own (the accel quadratic term contracts each step by
#: ~2 K2 |f| ~ 1e-4, so one is normally enough; more means a term too large to invert).
MAX_REFINE_STEPS = 8
#: Largest forward-model mismatch accepted, relative to the output's magnitude per sample.
RESIDUAL_TOLERANCE = 1e-13
#: Context keys an applier can fill from a recording.
_SUPPLIED = frozenset({"temperature_c", "temperature_rate_c_per_h", "time_h", "specific_force_g"})


@dataclass(frozen=True, eq=False)
class Calibrated:
    """Calibrated inputs, one row per sample: ``gyro`` (N, 3) in ``gyro_unit``, ``accel``
    (N, 3) in ``accel_unit``; None for a triad that was not given or that the set lacks."""

    gyro: np.ndarray | None
    accel: np.ndarray | None
    gyro_unit: str
    accel_unit: str


def _as_set(coefficients: CoefficientSet | Mapping[str, Any], terms: Mapping[str, Term] | None):
    if isinstance(coefficients, CoefficientSet):
        return coefficients
    if isinstance(coefficients, Mapping):
        return read_coefficients(coefficients, terms, source="coefficients")
    raise RecalInputError(
        f"coefficients must be a CoefficientSet or the parsed JSON object, not "
        f"{type(coefficients).__name__}"
    )


def triad_models(
    coefficients: CoefficientSet, terms: Mapping[str, Term] | None = None
) -> dict[str, Model]:
    """The model of each triad the set calibrates (it has that triad's scale): the seed terms
    plus the catalogue effects it carries (T0 from the set) or ``terms`` (a plugin's)."""
    known = {**catalogue_terms(coefficients.t0_c), **(terms or {})}
    extra: dict[str, list[Term]] = {"gyro": [], "accel": []}
    for name in coefficients.values:
        sensor, key = name.split(".", 1)
        if key in ("scale", "bias", "misalignment", "quadratic"):
            continue
        if name not in known:
            raise RecalInputError(
                f"coefficients carry effect '{name}', which is not in the catalogue: "
                "give its plugin file"
            )
        extra[sensor].append(known[name])
    models = {}
    for sensor in ("gyro", "accel"):
        if coefficients.get(f"{sensor}.scale") is not None:
            models[sensor] = Model.seed(sensor, extra[sensor])
        elif extra[sensor]:
            raise RecalInputError(f"coefficients carry {sensor} effects but no {sensor}.scale")
    if not models:
        raise RecalInputError("coefficients hold neither gyro.scale nor accel.scale")
    for model in models.values():
        unknown = model.needs - _SUPPLIED
        if unknown:
            raise RecalInputError(
                f"the {model.sensor} model needs {', '.join(sorted(unknown))}, which applying "
                "to a recording cannot supply"
            )
    if "specific_force_g" in models.get("gyro", Model("gyro", ())).needs and "accel" not in models:
        raise RecalInputError("gyro.g_sensitivity needs the accel coefficients too")
    return models


class Applier:
    """Applies one coefficient set to a recording fed in chunks (see the module doc).

    ``gyro_unit``: one of :data:`GYRO_UNITS`; ``accel_unit``: one of :data:`ACCEL_UNITS`.
    ``session_start_s``: time origin of a ``gyro.bias_drift`` term (default: the first sample
    fed). Feeding the same samples in one call or in many gives the same result.
    """

    def __init__(
        self,
        coefficients: CoefficientSet | Mapping[str, Any],
        gyro_unit: str = "deg/h",
        accel_unit: str = "g",
        terms: Mapping[str, Term] | None = None,
        session_start_s: float | None = None,
    ) -> None:
        if gyro_unit not in GYRO_UNITS:
            raise RecalInputError(f"gyro unit {gyro_unit!r} is not one of {', '.join(GYRO_UNITS)}")
        if accel_unit not in ACCEL_UNITS:
            raise RecalInputError(
                f"accel unit {accel_unit!r} is not one of {', '.join(ACCEL_UNITS)}"
            )
        self.coefficients = _as_set(coefficients, terms)
        self.models = triad_models(self.coefficients, terms)
        self.gyro_unit, self.accel_unit = gyro_unit, accel_unit
        self._theta = {
            s: self.coefficients.to_vector(ParameterLayout((m,)))[None]
            for s, m in self.models.items()
        }
        self._start_s = session_start_s
        self._history_t = np.zeros(0)  # the last TEMPERATURE_RATE_SPAN_S of temperature
        self._history_temp = np.zeros(0)

    @property
    def needs(self) -> frozenset[str]:
        """Context the set's terms need (``temperature_c``, ``time_h``, ...)."""
        return frozenset().union(*(m.needs for m in self.models.values()))

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.models)

    def __call__(
        self,
        time_s: np.ndarray | None,
        gyro: np.ndarray | None,
        accel: np.ndarray | None,
        temperature_c: np.ndarray | None = None,
    ) -> Calibrated:
        """The next chunk: ``gyro``, ``accel`` (n, 3) in output units, ``temperature_c`` (n,),
        ``time_s`` (n,) (needed by drift and temperature-rate terms only)."""
        n = _rows(gyro, accel)
        if n == 0:
            empty = np.zeros((0, 3))
            return Calibrated(
                empty if "gyro" in self.models and gyro is not None else None,
                empty if "accel" in self.models and accel is not None else None,
                self.gyro_unit,
                self.accel_unit,
            )
        ctx = self._context(n, time_s, temperature_c)
        force = None
        if "accel" in self.models and accel is not None:
            force = self._invert("accel", _triad(accel, n, "accel"), ctx)
        elif "specific_force_g" in self.needs and "gyro" in self.models and gyro is not None:
            raise RecalInputError("gyro.g_sensitivity needs the accel outputs too")
        rate = None
        if "gyro" in self.models and gyro is not None:
            ctx_g = ctx if force is None else {**ctx, "specific_force_g": force}
            rate = self._invert("gyro", _triad(gyro, n, "gyro"), ctx_g)
        return Calibrated(
            None if rate is None else rate * GYRO_UNITS[self.gyro_unit],
            None if force is None else force * ACCEL_UNITS[self.accel_unit],
            self.gyro_unit,
            self.accel_unit,
        )

    # ---- context --------------------------------------------------------------------------
    def _context(
        self, n: int, time_s: np.ndarray | None, temperature_c: np.ndarray | None
    ) -> dict[str, np.ndarray]:
        needs = self.needs
        ctx: dict[str, np.ndarray] = {}
        if needs & {"temperature_c", "temperature_rate_c_per_h"}:
            if temperature_c is None:
                names = sorted(t.name for m in self.models.values() for t in m.terms if t.needs)
                raise RecalInputError(
                    f"the coefficients' {', '.join(names)} need the temperature, which the "
                    "recording lacks"
                )
            ctx["temperature_c"] = _column(temperature_c, n, "temperature_c")
        if needs & {"time_h", "temperature_rate_c_per_h"}:
            if time_s is None:
                raise RecalInputError("the coefficients' drift or temperature-rate terms need time")
            t = _column(time_s, n, "time_s")
            if self._start_s is None and n:
                self._start_s = float(t[0])
            ctx["time_h"] = (t - (self._start_s or 0.0)) / 3600.0
            if "temperature_rate_c_per_h" in needs:
                ctx["temperature_rate_c_per_h"] = self._temperature_rate(t, ctx["temperature_c"])
        return ctx

    def _temperature_rate(self, t: np.ndarray, temp: np.ndarray) -> np.ndarray:
        """dT/dt in degC/h: from the earliest sample within the last minute to this one
        (0 for the very first sample)."""
        all_t = np.concatenate([self._history_t, t])
        all_temp = np.concatenate([self._history_temp, temp])
        here = np.arange(self._history_t.size, all_t.size)
        first = np.searchsorted(all_t, all_t[here] - TEMPERATURE_RATE_SPAN_S, side="left")
        span_s = all_t[here] - all_t[first]
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = np.where(span_s > 0, (all_temp[here] - all_temp[first]) / span_s * 3600.0, 0.0)
        keep = all_t >= all_t[-1] - TEMPERATURE_RATE_SPAN_S
        self._history_t, self._history_temp = all_t[keep], all_temp[keep]
        return rate

    # ---- the inverse ----------------------------------------------------------------------
    def _invert(self, sensor: str, out: np.ndarray, ctx: Mapping[str, np.ndarray]) -> np.ndarray:
        """Outputs (n, 3) -> true inputs (n, 3) in the model's units (deg/h or g), refined
        until the forward model reproduces ``out`` (see the module doc)."""
        model, theta = self.models[sensor], self._theta[sensor]
        x = model.inverse(theta, out, ctx)[0]
        # The refinement step's matrix: the nominal diag(K) (I + E); what it leaves out
        # (temperature scale, K2, asymmetry: 1e-3 at most) only slows the convergence.
        step = _nominal_inverse(self.coefficients, sensor)
        K = np.abs(self.coefficients.get(f"{sensor}.scale"))
        given = _finite_rows(out, ctx)  # a lost value (NaN) in, NaN out: not a failure
        for _ in range(MAX_REFINE_STEPS):
            with np.errstate(over="ignore", invalid="ignore"):  # a diverging sample is reported
                residual = model.forward(theta, x, ctx)[0] - out
                # per sample: the output's size, or the input's when terms cancel (x near -b)
                size = np.maximum(np.abs(out).max(axis=1), np.abs(x * K).max(axis=1))[:, None]
                close = np.abs(residual) <= RESIDUAL_TOLERANCE * size  # False where NaN
                if np.all(close[given]):
                    return x
                x = x - residual @ step.T
        raise RecalInputError(
            f"the {sensor} model cannot be inverted for some samples (a nonlinear term too "
            "large for the input, e.g. K2 * |f| near 0.5)"
        )


def _finite_rows(out: np.ndarray, ctx: Mapping[str, np.ndarray]) -> np.ndarray:
    """Samples whose outputs and per-sample context are all finite."""
    n = out.shape[0]
    ok = np.isfinite(out).all(axis=1)
    for value in ctx.values():
        arr = np.asarray(value, dtype=float)
        if arr.ndim and arr.shape[0] == n:
            ok &= np.isfinite(arr.reshape(n, -1)).all(axis=1)
    return ok


def _nominal_inverse(coefficients: CoefficientSet, sensor: str) -> np.ndarray:
    """(diag(K) (I + E))^-1 from the set's scale and misalignment."""
    K = coefficients.get(f"{sensor}.scale")
    E = np.eye(3)
    mis = coefficients.get(f"{sensor}.misalignment")
    if mis is not None:
        for (r, c), v in zip(MISALIGNMENT_INDEX, mis, strict=True):
            E[r, c] = v
    return inv3((K[:, None] * E)[None])[0]


def _rows(gyro: np.ndarray | None, accel: np.ndarray | None) -> int:
    for a in (gyro, accel):
        if a is not None:
            return int(np.shape(a)[0])
    raise RecalInputError("neither gyro nor accel outputs were given")


def _triad(a: np.ndarray, n: int, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.shape != (n, 3):
        raise RecalInputError(f"{name} must have shape ({n}, 3), got {arr.shape}")
    return arr


def _column(a: np.ndarray, n: int, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float).reshape(-1)
    if arr.shape != (n,):
        raise RecalInputError(f"{name} must have {n} values, got {arr.size}")
    return arr


def apply(
    coefficients: CoefficientSet | Mapping[str, Any],
    gyro: np.ndarray | None,
    accel: np.ndarray | None,
    temperature: np.ndarray | None = None,
    *,
    time_s: np.ndarray | None = None,
    gyro_unit: str = "deg/h",
    accel_unit: str = "g",
    terms: Mapping[str, Term] | None = None,
) -> Calibrated:
    """Calibrated rates and specific forces from raw outputs (docs/apply.md), vectorised.

    ``coefficients``: a :class:`CoefficientSet`, or the parsed JSON of a coefficients file, a
    ``recal calibrate --json`` output or the daemon's published file. ``gyro``, ``accel``:
    (N, 3) outputs in the sensor's output units (either may be None); ``temperature``: (N,)
    degC, needed by temperature terms; ``time_s``: (N,) s, needed by drift and temperature-rate
    terms (the drift's origin is ``time_s[0]``). ``gyro_unit``: deg/h, deg/s or rad/s;
    ``accel_unit``: g or m/s^2. ``terms``: a plugin's terms, for effects not in the catalogue.
    """
    applier = Applier(coefficients, gyro_unit, accel_unit, terms)
    return applier(time_s, gyro, accel, temperature)
