"""From the accepted versions of a model's units to its :class:`~recal.fleet.prior.FleetPrior`.

The rates are estimated by maximum likelihood (recal.fleet.estimate) over every change; the
units whose changes fail the outlier test (recal.fleet.outliers) are then set aside and the
rates estimated again without them (until the flags settle), so that a few units ageing ten times faster (a failing
source, a unit dropped in transit) neither inflate the figure sent to the others nor hide
among them. The units flagged are tested once more against the clean figure and listed in the
prior with their statistic.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

import numpy as np

from recal.fleet.estimate import random_walk_rate
from recal.fleet.history import Changes, VersionTable, is_relative
from recal.fleet.outliers import FALSE_ALARM, outlier_units
from recal.fleet.prior import CoefficientAgeing, FleetPrior

#: Rounds of "estimate, flag, set aside" at most (the flags settle in one or two).
MAX_ROUNDS = 4


def fleet_prior(
    versions: VersionTable | Changes,
    model: str,
    version: int = 1,
    false_alarm: float = FALSE_ALARM,
    created_at: str | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> FleetPrior:
    """The fleet prior of ``model`` from its units' accepted versions (or their changes).

    ``version``: the prior's own number, which the vessels record with every calibration that
    used it. ``false_alarm``: of the per-unit outlier test.
    """
    changes = versions.changes() if isinstance(versions, VersionTable) else versions
    est = random_walk_rate(changes.delta, changes.months, changes.variance)
    outliers = outlier_units(changes, est.rate, false_alarm)
    clean, aside = changes, set()
    for _ in range(MAX_ROUNDS):  # set aside the flagged units until the flags settle
        if {o.unit for o in outliers} == aside:
            break
        aside = {o.unit for o in outliers}
        clean = changes.without(sorted(aside))
        est = random_walk_rate(clean.delta, clean.months, clean.variance)
        outliers = outlier_units(changes, est.rate, false_alarm)
    seen = np.isfinite(clean.delta)
    units = np.zeros((len(clean.units), len(clean.names)))
    np.add.at(units, clean.unit, seen)  # changes per unit and coefficient
    units = units > 0
    coefficients = {
        name: CoefficientAgeing(
            float(est.rate[j]),
            float(est.rate_sigma[j]),
            is_relative(name),
            int(units[:, j].sum()),
            int(est.changes[j]),
        )  # fmt: skip
        for j, name in enumerate(clean.names)
    }
    when = created_at or datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return FleetPrior(model, int(version), when, coefficients, float(false_alarm),
                      tuple(outliers), metadata=dict(metadata or {}))  # fmt: skip
