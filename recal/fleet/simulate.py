"""A simulated ageing fleet: units of one model whose coefficients random-walk with known
per-coefficient spreads, recalibrated at realistic intervals with realistic sigmas.

Each unit starts from the model's nominal coefficients plus a unit-to-unit spread, and ages
as a random walk with the model's per-coefficient rate (``rates``: 1-sigma change after one
month; a fraction of the value for scale factors, recal.fleet.history.is_relative). A few
``outliers`` age ``outlier_factor`` times faster. A unit is recalibrated after gaps drawn
between ``interval_months`` (realistic: a static period at berth every one to six months).

The sigmas are a sigma model, not a calibration per version (200 units x 5 years would be
thousands of calibrations): each version reports ``sigma`` (P,) -- the 1-sigma a real
``calibrate`` of a design gives, which the caller takes from one (tests and the benchmark use
the simulated 24-position design's) -- times a per-version factor drawn uniformly in
``sigma_spread`` (a berth with more or fewer windows, calmer or rougher), and its estimate is
the truth plus that much Gaussian error. Vectorised over units and versions.

**The vessels' gate** (issue 37). With ``gate`` (the ``[gate] max_change_sigma`` of every
vessel), each version after a unit's first is put to the acceptance gate's jump rule as
service/gate.py states it: rejected when any coefficient moved more than ``gate`` times
``hypot(sigma_new, sigma_accepted, ageing)`` from the unit's current accepted version, where
``ageing`` is the fleet prior's ``gate_rates`` (``None``: no prior, no ageing allowed) times the
square root of the months since that accepted version (times the new value for scale factors,
as ``FleetPrior.typical_change``), and only from ``prior_from_months`` of service on (before it
the vessels had no prior yet). A rejected version keeps the current accepted one; the table holds
every version with ``accepted`` saying which passed. The gate's other limits (residuals,
observability) reject independently of the coefficients and are not simulated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recal.fleet.history import VersionTable, is_relative


@dataclass(frozen=True)
class SimulatedFleet:
    versions: VersionTable
    rates: np.ndarray  # (P,) the true rates
    outliers: tuple[str, ...]  # units that age faster
    truth: np.ndarray  # (V, P) the true coefficients at each version
    factor: np.ndarray | None = None  # (units,) each unit's rate factor (1, or outlier_factor)


def simulate_fleet(
    names: Sequence[str],
    nominal: np.ndarray,
    rates: np.ndarray,
    sigma: np.ndarray,
    units: int = 200,
    years: float = 5.0,
    interval_months: tuple[float, float] = (1.0, 6.0),
    sigma_spread: tuple[float, float] = (0.7, 1.5),
    outliers: int = 0,
    outlier_factor: float = 5.0,
    seed: int = 0,
    prefix: str = "SN",
    gate: float | None = None,
    gate_rates: np.ndarray | None = None,
    prior_from_months: float = 0.0,
) -> SimulatedFleet:
    """A fleet of ``units`` units of one model over ``years`` (see the module docstring)."""
    rng = np.random.default_rng(seed)
    names = tuple(names)
    nominal, rates, sigma = (np.asarray(x, float) for x in (nominal, rates, sigma))
    p = len(names)
    lo, hi = interval_months
    most = int(np.ceil(12.0 * years / lo)) + 1
    gaps = rng.uniform(lo, hi, (units, most))
    gaps[:, 0] = 0.0  # the first version: commissioning
    t = np.cumsum(gaps, axis=1)
    keep = t <= 12.0 * years
    factor = np.ones(units)
    bad = rng.choice(units, size=outliers, replace=False) if outliers else np.zeros(0, int)
    factor[bad] = outlier_factor
    rel = np.array([is_relative(n) for n in names])
    start = nominal * (1.0 + np.where(rel, 1e-4, 0.0) * rng.standard_normal((units, p)))
    dt = np.diff(t, axis=1, prepend=0.0)
    steps = rng.standard_normal((units, most, p)) * np.sqrt(dt)[..., None]
    walk = np.cumsum(steps, axis=1) * rates * factor[:, None, None]
    truth = np.where(rel, start[:, None, :] * (1.0 + walk), start[:, None, :] + walk)
    sd = sigma * rng.uniform(*sigma_spread, (units, most, 1))
    measured = truth + sd * rng.standard_normal(truth.shape)
    accepted = np.ones(keep.shape, bool)
    if gate is not None:
        allowed = np.zeros(p) if gate_rates is None else np.asarray(gate_rates, float)
        accepted = _gated(t, measured, sd, rel, allowed, float(gate), prior_from_months)
    unit = np.broadcast_to(np.arange(units)[:, None], keep.shape)[keep]
    labels = tuple(f"{prefix}{i:04d}" for i in range(units))
    table = VersionTable(names, labels, unit, t[keep], measured[keep], sd[keep], accepted[keep])
    return SimulatedFleet(table, rates, tuple(labels[i] for i in np.sort(bad)), truth[keep],
                          factor)  # fmt: skip


def _gated(
    t: np.ndarray,
    measured: np.ndarray,
    sd: np.ndarray,
    rel: np.ndarray,
    allowed: np.ndarray,
    limit: float,
    prior_from_months: float,
) -> np.ndarray:
    """(units, versions) bool: the jump rule of service/gate.py against each unit's current
    accepted version, version after version (vectorised over units; the decisions are
    sequential in time by nature: each depends on the last accepted)."""
    units, most, _ = measured.shape
    accepted = np.ones((units, most), bool)
    last = np.zeros(units, int)  # each unit's current accepted version
    rows = np.arange(units)
    for k in range(1, most):
        ref, ref_sd, ref_t = measured[rows, last], sd[rows, last], t[rows, last]
        months = np.maximum(t[:, k] - ref_t, 0.0)
        ageing = allowed * np.sqrt(months)[:, None]
        ageing = np.where(rel, ageing * np.abs(measured[:, k]), ageing)
        ageing = np.where((t[:, k] >= prior_from_months)[:, None], ageing, 0.0)
        combined = np.sqrt(sd[:, k] ** 2 + ref_sd**2 + ageing**2)
        ok = np.all(np.abs(measured[:, k] - ref) <= limit * combined, axis=1)
        accepted[:, k] = ok
        last = np.where(ok, k, last)
    return accepted
