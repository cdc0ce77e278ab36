"""Units whose changes are outliers for their model.

From a :class:`~recal.fleet.history.VersionTable` (issue 37): a unit's statistic is the quadratic
form of its whole sequence of versions under the model's rates (recal.fleet.sequence: the
differences with their tridiagonal covariance, consecutive ones sharing a version's error),
summed over its coefficients: chi-square with as many degrees of freedom as differences, exactly,
under "this unit ages like its model".

From :class:`~recal.fleet.history.Changes` (the form before issue 37, kept for callers that
have only the changes): each change of each coefficient of a unit is Gaussian with
variance ``s**2 dt + sigma_1**2 + sigma_2**2`` (recal.fleet.estimate). The unit's statistic is
the sum of its squared normalised changes over every change and coefficient, chi-square with as
many degrees of freedom as terms under the null hypothesis "this unit ages like its model". A
unit is flagged when its p-value is below the stated false-alarm rate (default 1 %: about one
unit in a hundred that ages like the others is flagged). Summed per unit with np.bincount (no
loop over units or changes).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from recal.fleet.history import Changes, VersionTable
from recal.fleet.prior import FleetOutlier
from recal.fleet.sequence import Chain, version_chain

#: The outlier test's default false-alarm rate per unit.
FALSE_ALARM = 0.01


def unit_statistics(
    changes: Changes | VersionTable | Chain, rate: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(statistic, dof) per unit of ``changes.units`` under the per-coefficient ``rate`` (P,)."""
    if isinstance(changes, VersionTable):
        changes = version_chain(changes)
    if isinstance(changes, Chain):
        return changes.unit_statistics(np.asarray(rate, float) ** 2)
    v = rate[None, :] ** 2 * changes.months[:, None] + changes.variance
    ok = np.isfinite(changes.delta) & np.isfinite(v) & (v > 0)
    z2 = np.where(ok, changes.delta**2 / np.where(ok, v, 1.0), 0.0)
    n = len(changes.units)
    stat = np.bincount(changes.unit, weights=z2.sum(1), minlength=n)
    dof = np.bincount(changes.unit, weights=ok.sum(1), minlength=n).astype(int)
    return stat, dof


def outlier_units(
    changes: Changes | VersionTable | Chain, rate: np.ndarray, false_alarm: float = FALSE_ALARM
) -> list[FleetOutlier]:
    """Units whose changes fail the chi-square test at ``false_alarm``, largest excess first."""
    stat, dof = unit_statistics(changes, rate)
    p = np.where(dof > 0, chi2.sf(stat, np.maximum(dof, 1)), 1.0)
    flagged = np.flatnonzero(p < false_alarm)
    flagged = flagged[np.argsort(p[flagged], kind="stable")]
    return [FleetOutlier(changes.units[i], float(stat[i]), int(dof[i]), float(p[i]))
            for i in flagged]  # fmt: skip
