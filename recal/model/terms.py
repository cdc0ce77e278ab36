"""Physical terms of the sensor error models.

A triad's output is modelled (docs/reference.md#models) as

    N = K_eff ⊙ [ A x + Σ nonlinear(x) + Σ offset ]

with ``x`` the true input (deg/h for the gyro, g for the accelerometer), ``K_eff`` the product of
every term's multiplicative ``scale`` factor, ``A = I + Σ matrix`` and the offsets additive in input
units. Each :class:`Term` contributes to one or more of those slots; a :class:`~recal.model.error_model.Model`
composes them. Everything is batched: parameters arrive as ``p`` of shape (P, n_params) for P
candidate parameter vectors (P = 1 for LM, fish × runs for a swarm) and contributions broadcast
against (P, M, 3) for M positions. A new term never touches a solver.

To add an effect of your own, subclass :class:`Term` in a Python file and pass it with
``--plugin FILE.py`` (the file defines ``TERMS = [MyTerm(), ...]``). ``recal diagnose`` then
tries it as a candidate; ``recal calibrate`` fits it when it is named in ``--effects``. The file
is checked on load (:func:`recal.model.plugins.validate_terms`): the name is ``sensor.effect`` with
the sensor prefix, ``typical`` and ``neutral`` have one number per parameter, and a trial
evaluation must return arrays that broadcast to (P, M, 3) ((P, 3, 3) for ``matrix``), finite,
vanishing at ``neutral``. A mistake exits 2 naming the file, the term and the problem.

The context ``ctx`` a contribution receives holds exactly the keys the term lists in ``needs``:

=============================  =========  ===================================================
key                            shape      meaning
=============================  =========  ===================================================
``temperature_c``              (M,)       mean temperature of each window, degC
``temperature_rate_c_per_h``   (M,)       temperature slope over the window, degC/h
``time_h``                     (M,)       window middle, hours from the session start
``specific_force_g``           (M, 3)     specific force in body axes, g (accel at the prior)
``gravity_direction``          (M, 3)     unit vector of the measured specific force (up)
``earth_rate_direction``       (M, 3)     unit vector of the measured rate
``north``, ``east``            (M, 3)     local north and east in body axes (both triads)
``latitude_deg``               scalar     site latitude
``gravity_g``                  scalar     local normal gravity, g
``earth_rate_deg_h``           scalar     Earth rate, deg/h
any other positions column     (M,)       e.g. ``mag_x``, when the CSV has it
=============================  =========  ===================================================

The directions are measured (outputs corrected with the prior's scale and bias), so no
attitude is needed: a field fixed in the local frame is ``B_N north + B_E east + B_U
gravity_direction`` in body axes (``docs/examples/faraday_plugin.py``). A coefficients file
written with a plugin effect records the plugin's file (``metadata.plugins``); using it as
``--prior`` without that ``--plugin`` is an input error.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

AXES = ("x", "y", "z")
#: Misalignment coefficient names in the order of docs/reference.md#coefficients / seed 000 Table 3.
MISALIGNMENT_NAMES = ("Exz", "Exy", "Eyz", "Eyx", "Ezy", "Ezx")
#: (row, column) of each name in E = [[0, Exz, Exy], [Eyz, 0, Eyx], [Ezy, Ezx, 0]]
#: (docs/reference.md#models, seed 000 eq. 11): the antisymmetric pairs are Exz/Eyz,
#: Exy/Ezy, Eyx/Ezx.
MISALIGNMENT_INDEX = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))

_ROWS, _COLS = (np.array(ix) for ix in zip(*MISALIGNMENT_INDEX, strict=True))

Context = Mapping[str, np.ndarray]


@dataclass(frozen=True)
class Term:
    """One physical term of a sensor model.

    Attributes:
        name: catalogue name, e.g. ``"gyro.scale"`` (docs/reference.md#effects).
        sensor: ``"gyro"`` or ``"accel"``.
        params: parameter names, e.g. ``("Kx", "Ky", "Kz")``.
        units: unit of each parameter (one string for all, or one per parameter).
        typical: typical magnitude of the parameter's *change* between calibrations, per
            parameter. It sets the per-dimension swarm Visual, the LM scaling and the
            observability threshold (a direction is "estimated" when the data pin it down better
            than this).
        neutral: parameter values that make the term vanish (no effect).
        explanation: the one-line physical explanation shown to users.
        category: phase group for the seed's phased swarm (scale, bias, misalignment, quadratic);
            catalogue effects form their own category.
        needs: context columns required (e.g. ``"temperature_c"``).
        linearize_at_zero: evaluate the observability Jacobian with this term set to neutral.
            True for misalignment, whose rotational null directions are exact only at E = 0.
        relative_typical: ``typical`` is a fraction of the prior value (scale factors).
    """

    name: str
    sensor: str
    params: tuple[str, ...]
    units: str | tuple[str, ...]
    typical: tuple[float, ...]
    neutral: tuple[float, ...]
    explanation: str
    category: str = ""
    needs: frozenset[str] = field(default_factory=frozenset)
    linearize_at_zero: bool = False
    relative_typical: bool = False

    @property
    def size(self) -> int:
        return len(self.params)

    @property
    def group(self) -> str:
        return self.category or self.name.split(".", 1)[1]

    def unit_of(self, i: int) -> str:
        return self.units if isinstance(self.units, str) else self.units[i]

    # ---- contributions (override what applies; None means "no contribution") -----------
    def scale(self, p: np.ndarray, ctx: Context) -> np.ndarray | None:
        """Multiplicative factor on the output, broadcastable to (P, M, 3)."""
        return None

    def matrix(self, p: np.ndarray) -> np.ndarray | None:
        """Additive part of A = I + E, shape (P, 3, 3)."""
        return None

    def offset(self, p: np.ndarray, ctx: Context) -> np.ndarray | None:
        """Additive offset in input units, broadcastable to (P, M, 3); independent of x."""
        return None

    def nonlinear(self, p: np.ndarray, x: np.ndarray, ctx: Context) -> np.ndarray | None:
        """Additive term that depends on the true input x (P, M, 3), in input units."""
        return None

    def nonlinear_components(
        self, p: np.ndarray, x: list[np.ndarray], ctx: Context
    ) -> list[np.ndarray]:
        """:meth:`nonlinear` on component-major input: x as three (P, M) arrays, the result
        likewise. The default stacks; a per-axis term overrides it to stay on contiguous memory
        (the swarms' hot path, :meth:`recal.model.error_model.Model.inverse_components`)."""
        h = self.nonlinear(p, np.stack(x, axis=-1), ctx)
        return [h[..., i] for i in range(3)]


def _per_axis(p: np.ndarray) -> np.ndarray:
    """(P, 3) per-axis parameters as (P, 1, 3) so they broadcast over positions."""
    return p[:, None, :]


def _session_column(ctx: Context, key: str) -> np.ndarray:
    """(M,) context column as (1, M, 1)."""
    return np.asarray(ctx[key], dtype=float)[None, :, None]


# ------------------------------------------------------------------ the seed model's terms
@dataclass(frozen=True)
class ScaleTerm(Term):
    """K: output units per input unit, per axis (seed 000 eq. 11, seed 002 eq. 15)."""

    def scale(self, p: np.ndarray, ctx: Context) -> np.ndarray:
        return _per_axis(p)


@dataclass(frozen=True)
class BiasTerm(Term):
    """b: constant offset in input units, per axis."""

    def offset(self, p: np.ndarray, ctx: Context) -> np.ndarray:
        return _per_axis(p)


@dataclass(frozen=True)
class MisalignmentTerm(Term):
    """E: zero-diagonal misalignment matrix, small angles in rad (docs/reference.md#models)."""

    def matrix(self, p: np.ndarray) -> np.ndarray:
        E = np.zeros((p.shape[0], 3, 3))
        E[:, _ROWS, _COLS] = p
        return E


@dataclass(frozen=True)
class QuadraticTerm(Term):
    """K2: second-order nonlinearity K2 * f**2 (element-wise), 1/g."""

    def nonlinear(self, p: np.ndarray, x: np.ndarray, ctx: Context) -> np.ndarray:
        return _per_axis(p) * x * x

    def nonlinear_components(
        self, p: np.ndarray, x: list[np.ndarray], ctx: Context
    ) -> list[np.ndarray]:
        return [p[:, i, None] * x[i] * x[i] for i in range(3)]  # the same products, per axis


# ------------------------------------------------------------------ catalogue effects (section 7)
@dataclass(frozen=True)
class ColumnBiasTerm(Term):
    """b += k (c - origin), per axis, for a per-position context column c: temperature
    (origin T0), temperature rate (the Shupe effect) or session time (a drift)."""

    column: str = "temperature_c"
    origin: float = 0.0

    def offset(self, p: np.ndarray, ctx: Context) -> np.ndarray:
        return _per_axis(p) * (_session_column(ctx, self.column) - self.origin)


@dataclass(frozen=True)
class TemperatureScaleTerm(Term):
    """K *= 1 + s_T (T - T0), per axis."""

    t0_c: float = 25.0

    def scale(self, p: np.ndarray, ctx: Context) -> np.ndarray:
        return 1.0 + _per_axis(p) * (_session_column(ctx, "temperature_c") - self.t0_c)


@dataclass(frozen=True)
class GSensitivityTerm(Term):
    """b_g += G f with G a 3x3 matrix (deg/h per g); f is the specific force at the position."""

    def offset(self, p: np.ndarray, ctx: Context) -> np.ndarray:
        G = p.reshape(p.shape[0], 3, 3)
        f = np.asarray(ctx["specific_force_g"], dtype=float)  # (M, 3)
        return np.einsum("pij,mj->pmi", G, f)


@dataclass(frozen=True)
class ScaleAsymmetryTerm(Term):
    """Scale K(1 + a) for positive and K(1 - a) for negative input: adds a |x| per axis."""

    def nonlinear(self, p: np.ndarray, x: np.ndarray, ctx: Context) -> np.ndarray:
        return _per_axis(p) * np.abs(x)


def _xyz(prefix: str) -> tuple[str, str, str]:
    return tuple(f"{prefix}{a}" for a in AXES)  # type: ignore[return-value]


def seed_terms(sensor: str) -> list[Term]:
    """The seed papers' categories: scale, bias, misalignment (and quadratic for the accel)."""
    if sensor == "gyro":
        terms: list[Term] = [
            ScaleTerm(
                "gyro.scale",
                "gyro",
                _xyz("K"),
                "output/(deg/h)",
                (1e-3,) * 3,
                (1.0,) * 3,
                "Scale factor: output units per deg/h of input rate.",
                "scale",
                relative_typical=True,
            ),
            BiasTerm(
                "gyro.bias",
                "gyro",
                _xyz("b"),
                "deg/h",
                (0.05,) * 3,
                (0.0,) * 3,
                "Bias: rate read at zero input, deg/h.",
                "bias",
            ),
            MisalignmentTerm(
                "gyro.misalignment",
                "gyro",
                MISALIGNMENT_NAMES,
                "rad",
                (1e-3,) * 6,
                (0.0,) * 6,
                "Axis misalignment: small angles between sensing axes.",
                "misalignment",
                linearize_at_zero=True,
            ),
        ]
        return terms
    if sensor == "accel":
        return [
            ScaleTerm(
                "accel.scale",
                "accel",
                _xyz("K"),
                "output/g",
                (1e-3,) * 3,
                (1.0,) * 3,
                "Scale factor: output units per g of specific force.",
                "scale",
                relative_typical=True,
            ),
            BiasTerm(
                "accel.bias",
                "accel",
                _xyz("b"),
                "g",
                (1e-3,) * 3,
                (0.0,) * 3,
                "Bias: specific force read at zero input, g.",
                "bias",
            ),
            MisalignmentTerm(
                "accel.misalignment",
                "accel",
                MISALIGNMENT_NAMES,
                "rad",
                (1e-3,) * 6,
                (0.0,) * 6,
                "Axis misalignment: small angles between sensing axes.",
                "misalignment",
                linearize_at_zero=True,
            ),
            QuadraticTerm(
                "accel.quadratic",
                "accel",
                _xyz("K2"),
                "1/g",
                (1e-4,) * 3,
                (0.0,) * 3,
                "Second-order nonlinearity: output grows with f**2.",
                "quadratic",
            ),
        ]
    raise ValueError(f"unknown sensor {sensor!r}")


def catalogue_terms(t0_c: float = 25.0) -> dict[str, Term]:
    """The named physical effects of docs/reference.md#effects, keyed by name."""
    g9 = tuple(f"G{r}{c}" for r in AXES for c in AXES)
    terms: list[Term] = [
        ColumnBiasTerm(
            "gyro.bias_temperature",
            "gyro",
            _xyz("kT"),
            "deg/h/degC",
            (0.01,) * 3,
            (0.0,) * 3,
            "Bias changes with temperature (coil and source thermal sensitivity).",
            "",
            frozenset({"temperature_c"}),
            column="temperature_c",
            origin=t0_c,
        ),
        TemperatureScaleTerm(
            "gyro.scale_temperature",
            "gyro",
            _xyz("sT"),
            "1/degC",
            (1e-5,) * 3,
            (0.0,) * 3,
            "Scale factor changes with temperature (source wavelength and coil length).",
            "",
            frozenset({"temperature_c"}),
            t0_c=t0_c,
        ),
        ColumnBiasTerm(
            "gyro.bias_temperature_rate",
            "gyro",
            _xyz("kdT"),
            "deg/h/(degC/h)",
            (0.01,) * 3,
            (0.0,) * 3,
            "Bias from a temperature gradient across the coil (Shupe "
            "effect), proportional to dT/dt.",
            "",
            frozenset({"temperature_rate_c_per_h"}),
            column="temperature_rate_c_per_h",
        ),
        GSensitivityTerm(
            "gyro.g_sensitivity",
            "gyro",
            g9,
            "deg/h/g",
            (0.01,) * 9,
            (0.0,) * 9,
            "Bias proportional to specific force (mechanical stress on the coil).",
            "",
            frozenset({"specific_force_g"}),
        ),
        ColumnBiasTerm(
            "gyro.bias_drift",
            "gyro",
            _xyz("d"),
            "deg/h/h",
            (0.005,) * 3,
            (0.0,) * 3,
            "Bias drifts linearly over the session (ageing, warm-up).",
            "",
            frozenset({"time_h"}),
            column="time_h",
        ),
        ColumnBiasTerm(
            "accel.bias_temperature",
            "accel",
            _xyz("kT"),
            "g/degC",
            (2e-5,) * 3,
            (0.0,) * 3,
            "Bias changes with temperature (pendulum and electronics).",
            "",
            frozenset({"temperature_c"}),
            column="temperature_c",
            origin=t0_c,
        ),
        TemperatureScaleTerm(
            "accel.scale_temperature",
            "accel",
            _xyz("sT"),
            "1/degC",
            (2e-5,) * 3,
            (0.0,) * 3,
            "Scale factor changes with temperature (magnet and torquer).",
            "",
            frozenset({"temperature_c"}),
            t0_c=t0_c,
        ),
        ScaleAsymmetryTerm(
            "accel.scale_asymmetry",
            "accel",
            _xyz("a"),
            "1",
            (1e-4,) * 3,
            (0.0,) * 3,
            "Different scale factor for positive and negative input.",
            "",
        ),
    ]
    return {t.name: t for t in terms}
