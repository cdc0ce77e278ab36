"""From the versions of a model's units to its :class:`~recal.fleet.prior.FleetPrior`.

From a :class:`~recal.fleet.history.VersionTable` (issue 37): the rates are estimated by
maximum likelihood of every unit's whole sequence of versions, accepted and rejected by the gate
for a jump (recal.fleet.sequence: why the rejected ones, and why the sequence rather than its
changes). From :class:`~recal.fleet.history.Changes`: as before issue 37, every change taken as
independent (recal.fleet.estimate), kept for callers that have only the changes.

Either way the units whose changes fail the outlier test (recal.fleet.outliers) beyond doubt
(p-value below ``SET_ASIDE``) are then set aside and the rates estimated again without them
(until the flags settle), so that a few units ageing faster (a failing source, a unit dropped in
transit) neither inflate the figure sent to the others nor hide among them. The units flagged at
``false_alarm`` are tested once more against the clean figure and listed in the prior with their
statistic. Only the flags beyond doubt are set aside (issue 37): at 1 % about two units in 200
that age like the others are flagged, and they are the ones whose changes happened to be
largest, so setting them aside too biased every rate low (by a tenth of its own 1-sigma, on the
simulated fleets of benchmarks/bench_fleet_prior.py) and its 95 % interval covered less; a unit
ageing twice as fast over a few years is beyond doubt (p far below 1e-10 there).
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

import numpy as np

from recal.fleet.estimate import RateEstimate, random_walk_rate
from recal.fleet.history import Changes, VersionTable, is_relative
from recal.fleet.outliers import FALSE_ALARM, outlier_units
from recal.fleet.prior import CoefficientAgeing, FleetOutlier, FleetPrior
from recal.fleet.sequence import Chain, version_chain

#: Rounds of "estimate, flag, set aside" at most (the flags settle in one or two).
MAX_ROUNDS = 4
#: A flagged unit is set aside from the estimate when its p-value is below this.
SET_ASIDE = 1e-4


def fleet_prior(
    versions: VersionTable | Changes,
    model: str,
    version: int = 1,
    false_alarm: float = FALSE_ALARM,
    created_at: str | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> FleetPrior:
    """The fleet prior of ``model`` from its units' versions (or their changes).

    ``versions``: a :class:`VersionTable` of the accepted versions and those the gate rejected
    for a jump (``accepted`` says which), or :class:`Changes` (the estimate before issue 37).
    ``version``: the prior's own number, which the vessels record with every calibration that
    used it. ``false_alarm``: of the per-unit outlier test.
    """
    data: Chain | Changes = (
        version_chain(versions) if isinstance(versions, VersionTable) else versions
    )
    est, outliers, clean = _settle(data, false_alarm)
    if isinstance(clean, Chain):
        _, units, rejected = clean.counts()
    else:
        seen = np.isfinite(clean.delta)
        per_unit = np.zeros((len(clean.units), len(clean.names)))
        np.add.at(per_unit, clean.unit, seen)  # changes per unit and coefficient
        units, rejected = (per_unit > 0).sum(0), np.zeros(len(clean.names), int)
    coefficients = {
        name: CoefficientAgeing(
            float(est.rate[j]),
            float(est.rate_sigma[j]),
            is_relative(name),
            int(units[j]),
            int(est.changes[j]),
            int(rejected[j]),
        )  # fmt: skip
        for j, name in enumerate(clean.names)
    }
    when = created_at or datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return FleetPrior(model, int(version), when, coefficients, float(false_alarm),
                      tuple(outliers), metadata=dict(metadata or {}))  # fmt: skip


def _estimate(data: Chain | Changes) -> RateEstimate:
    if isinstance(data, Chain):
        return data.rate()
    return random_walk_rate(data.delta, data.months, data.variance)


def _settle(
    data: Chain | Changes, false_alarm: float
) -> tuple[RateEstimate, list[FleetOutlier], Chain | Changes]:
    """(the rates without the flagged units, the flagged units, the data behind the rates)."""
    est = _estimate(data)
    outliers = outlier_units(data, est.rate, false_alarm)
    clean, aside = data, set()
    for _ in range(MAX_ROUNDS):  # set aside the units beyond doubt until the flags settle
        doubtless = {o.unit for o in outliers if o.p_value < min(SET_ASIDE, false_alarm)}
        if doubtless == aside:
            break
        aside = doubtless
        clean = data.without(sorted(aside))
        est = _estimate(clean)
        outliers = outlier_units(data, est.rate, false_alarm)
    return est, outliers, clean
