"""What to calibrate and how: :class:`CalibrationOptions`, the one argument besides the
positions that :func:`recal.solve.calibrate.calibrate` takes. Its own module so that the fit's
parts (prior, slews, wander) can read it without importing the calibration that uses them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from recal.detect.known_rotations import KnownRotations
from recal.detect.slew_data import Slews
from recal.model.coefficients import CoefficientSet
from recal.model.terms import Term
from recal.solve.swarm import SwarmConfig


@dataclass(frozen=True)
class CalibrationOptions:
    """What to calibrate and how.

    sensor: "gyro", "accel", "both" or None (every triad present in the positions).
    method: "lm" (default), "nafsa", "safsa" or "oafsa".
    mc_runs: Monte Carlo repetitions for swarm methods (seed: 100).
    paper: run swarms as the seeds do (category phases in raw coordinates, literal CF,
        Table 1 Visual); default is the whitened joint phase over observable directions.
    polish: follow a swarm by LM from its mean.
    effects: extra terms by catalogue name; plugin_terms: user Term objects.
    """

    sensor: str | None = None
    method: str = "lm"
    mc_runs: int = 100
    seed: int = 0
    latitude_deg: float = 45.0
    height_m: float = 0.0
    prior: CoefficientSet | None = None
    effects: Sequence[str] = ()
    plugin_terms: Sequence[Term] = ()
    paper: bool = False
    polish: bool = False
    swarm_config: SwarmConfig | None = None
    #: swarm cycles (each re-whitens the phase and, with slews, re-linearises them at the runs'
    #: mean); 4: with slews 3 left the MC mean ~1 sigma from the minimum (benchmarks/bench_mcs_slews)
    cycles: int = 4
    indicator_threshold: float | None = None  # None: 1e-8 in paper mode (seed 000), else off
    t0_c: float = 25.0
    #: gyro increments between the windows (recal.detect.slew_data), or None
    slews: Slews | None = None
    known_rotations: KnownRotations | None = None  # commanded rotations of some slews
    #: declared closed turns: the 1-sigma, deg, of a slew that turns whole revolutions about the
    #: vertical where Earth rate cannot check it (recal.detect.closed_turns.turn_candidates); <= 0 (the
    #: default): none declared, only turns checked by the Earth-rate headings are closed
    turn_closure_sigma_deg: float = 0.0
    #: bias wander between windows (recal.solve.wander): None (windows independent), "auto"
    #: (estimated from the fit's residuals, kept when a likelihood-ratio test says so), or a
    #: WanderModel (given, e.g. from recal noise)
    wander: Any = None
    #: refuse a design that cannot show scale and bias at the solution; diagnose turns it off:
    #: a missing effect can drag the baseline fit there, and the candidates must still be tried
    refuse_at_solution: bool = True
    #: the fleet's ageing figures (:class:`recal.fleet.prior.FleetPrior`, issue 28): with
    #: ``prior_age_months`` (months of service since the prior's calibration), a held
    #: coefficient's 1-sigma adds the fleet's change over that time to the prior file's own, and
    #: replaces the datasheet's typical change where the file has none
    fleet_prior: Any = None
    prior_age_months: float | None = None
