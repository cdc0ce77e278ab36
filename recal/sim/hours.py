"""A session of hours as window means (issue 35): what a daemon or a user's logger collects.

:func:`simulate_hours` draws, per seed, 30 random orientations (``n_positions``) of 300 s
windows spread evenly over 4 to 8 h, a temperature that ramps and cycles (a swing of several
degC with a period of 1 to 3 h), a latitude in -70..70 deg, and both triads with the default
window noise (:class:`recal.sim.simulate.NoiseSpec`). On top of the seed truth it can hide one
effect (a catalogue name with its values, or a plugin :class:`~recal.model.terms.Term`) and a
Gauss-Markov bias wander. It also returns the prior a user has: the truth's seed coefficients
moved by about their change between calibrations (:data:`PRIOR_CHANGE`), so a diagnosis starts
where a real one does, not at the truth.

Pure numerics: no I/O. The window means come from
:func:`recal.sim.simulate.simulate_positions`, so the same seed gives the same orientations and
noise as that function with the same arguments.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from recal.model.coefficients import CoefficientSet
from recal.model.plugins import builtin_names, hidden_plugin
from recal.model.positions import Positions
from recal.model.terms import Term, catalogue_terms
from recal.sim.simulate import NoiseSpec, TemperatureSpec, design_orientations, simulate_positions

if TYPE_CHECKING:
    from recal.solve.options import CalibrationOptions

#: 1-sigma change of each seed coefficient between the prior and the truth, as measured over the
#: four sessions of ../shared/data/diagnose-hours (prior minus truth, RMS over axes and
#: sessions): scale factors relative (gyro 3.6e-4, i.e. ~0.23 output counts on a scale of ~645;
#: accel 3.2e-4), gyro bias deg/h, accel bias g, misalignment rad, accel quadratic 1/g.
PRIOR_CHANGE: dict[str, float] = {
    "gyro.scale": 3.6e-4,
    "gyro.bias": 0.011,
    "gyro.misalignment": 1.2e-4,
    "accel.scale": 3.2e-4,
    "accel.bias": 2.0e-4,
    "accel.misalignment": 1.0e-4,
    "accel.quadratic": 5e-6,
}
#: the coefficients whose PRIOR_CHANGE is relative to their value
RELATIVE = ("gyro.scale", "accel.scale")

WINDOW_S = 300.0
N_POSITIONS = 30
SPAN_H = (4.0, 8.0)
LATITUDE_DEG = (-70.0, 70.0)
START_C = (15.0, 30.0)
#: ramp, degC/h (either sign): a slow drift of the environment under the cycle
SLOPE_C_PER_H = (0.5, 2.0)
#: swing amplitude, degC, and period, h: a day-night-like cycle compressed into hours, as a
#: heated room or an engine room cycles; a full period or more in every session lets a
#: temperature effect be told from a drift in time
SWING_C = (4.0, 8.0)
PERIOD_H = (1.0, 3.0)


@dataclass(frozen=True)
class HoursSession:
    """One simulated session of hours and what a user would hand to ``recal diagnose``.

    ``hidden``: the hidden effect's name (None: nothing hidden); ``hidden_value``: its truth
    values; ``plugin_terms``: the plugin terms diagnose is given (``--plugin``);
    ``span_h``: first window start to last window end, h.
    """

    seed: int
    positions: Positions
    truth: CoefficientSet
    prior: CoefficientSet
    latitude_deg: float
    span_h: float
    temperature: TemperatureSpec
    noise: NoiseSpec
    hidden: str | None = None
    hidden_value: tuple[float, ...] | None = None
    plugin_terms: tuple[Term, ...] = ()

    def options(self, **overrides: Any) -> CalibrationOptions:
        """The options ``recal diagnose FILE --prior PRIOR --latitude LAT [--plugin ...]``
        builds (service/cli/calibrate.py options_from_args): the command line's default
        ``--wander auto`` included, which CalibrationOptions alone does not default to."""
        from recal.solve.options import CalibrationOptions

        kw: dict[str, Any] = {
            "latitude_deg": self.latitude_deg,
            "prior": self.prior,
            "plugin_terms": list(self.plugin_terms),
            "wander": "auto",
        }
        kw.update(overrides)
        return CalibrationOptions(**kw)


def session_draw(seed: int) -> tuple[float, float, TemperatureSpec]:
    """(latitude_deg, span_h, temperature) of a seed, from a stream of its own so the
    orientations and noise (``simulate_positions``' stream) do not depend on these draws."""
    rng = np.random.default_rng([seed, 35])
    lat = float(rng.uniform(*LATITUDE_DEG))
    span_h = float(rng.uniform(*SPAN_H))
    slope = float(rng.uniform(*SLOPE_C_PER_H) * rng.choice([-1.0, 1.0]))
    temp = TemperatureSpec(
        start_c=float(rng.uniform(*START_C)),
        slope_c_per_h=slope,
        swing_c=float(rng.uniform(*SWING_C)),
        period_h=float(rng.uniform(*PERIOD_H)),
    )
    return lat, span_h, temp


def perturbed_prior(truth: CoefficientSet, seed: int) -> CoefficientSet:
    """The truth's seed coefficients moved by normal draws of :data:`PRIOR_CHANGE` (no effect
    terms: a user's prior comes from a seed-model calibration)."""
    rng = np.random.default_rng([seed, 36])
    vals = {}
    for name, sd in PRIOR_CHANGE.items():
        v = np.array(truth.values[name], float)
        step = rng.normal(size=v.shape) * sd
        vals[name] = v * (1.0 + step) if name in RELATIVE else v + step
    return CoefficientSet(vals, truth.t0_c, {"source": f"simulated prior (seed {seed})"})


def simulate_hours(
    seed: int,
    hidden: str | Term | None = None,
    value: Sequence[float] | None = None,
    *,
    plugin_terms: Sequence[Term] = (),
    gm_gyro_dph: float = 0.0,
    gm_accel_ug: float = 0.0,
    gm_tau_s: float = 6 * 3600.0,
    n_positions: int = N_POSITIONS,
    window_s: float = WINDOW_S,
) -> HoursSession:
    """A session of hours (module doc) with ``hidden`` in the truth.

    hidden: a catalogue effect name, or a plugin term (bound to the true site context of the
        drawn orientations, :func:`recal.model.plugins.hidden_plugin`); None: a clean session.
    value: the hidden effect's truth values (default: its ``typical``).
    plugin_terms: the plugin terms a user passes to diagnose (not simulated).
    gm_gyro_dph, gm_accel_ug, gm_tau_s: Gauss-Markov bias wander (deg/h, micro-g, s), as in
        :class:`~recal.sim.simulate.NoiseSpec`; 0: none.
    """
    lat, span_h, temp = session_draw(seed)
    # evenly spaced windows: the last one ends span_h after the first starts
    spacing_s = (span_h * 3600.0 - window_s) / (n_positions - 1)
    noise = NoiseSpec(
        window_s=window_s,
        slew_s=spacing_s - window_s,
        gm_gyro_dph=gm_gyro_dph,
        gm_accel_ug=gm_accel_ug,
        gm_tau_s=gm_tau_s,
    )
    truth = CoefficientSet.seed_truth()
    terms: list[Term] = []
    name = None
    if hidden is not None:
        if isinstance(hidden, str):
            term = catalogue_terms(truth.t0_c)[hidden]
        else:
            if hidden.name in builtin_names():
                raise ValueError(f"{hidden.name} is built in: pass its name")
            # simulate_positions draws the orientations first from default_rng(seed)
            C_nb = design_orientations("random", n_positions, np.random.default_rng(seed))
            term = hidden_plugin(hidden, C_nb, lat)
        name = term.name
        v = np.asarray(term.typical if value is None else value, float)
        if v.shape != (term.size,):
            raise ValueError(f"{name} has {term.size} parameters, got {v.shape}")
        truth.values[name] = v
        terms.append(term)
    pos = simulate_positions(
        truth, "random", n_positions, lat, seed=seed, noise=noise, temperature=temp, hidden=terms
    )
    return HoursSession(
        seed=seed,
        positions=pos,
        truth=truth,
        prior=perturbed_prior(truth, seed),
        latitude_deg=lat,
        span_h=span_h,
        temperature=temp,
        noise=noise,
        hidden=name,
        hidden_value=None if name is None else tuple(float(x) for x in truth.values[name]),
        plugin_terms=tuple(plugin_terms),
    )
