"""The accepted coefficients' covariance for the drift test: from a calibration's matrix, a
coefficients file's ``"covariance"`` block (names + matrix), else its 1-sigma values as a
diagonal; and the block a coefficients file carries (:func:`covariance_to_json`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet


def coefficient_covariance(
    coefficients: CoefficientSet,
    layout,
    covariance: np.ndarray | Mapping[str, Any] | None,
    notes: list[str],
) -> np.ndarray:
    """(D, D) covariance of the accepted coefficients in ``layout``'s order: ``covariance`` as an
    array in that order, or as the coefficients file's ``"covariance"`` block (names + matrix,
    :func:`covariance_to_json`), else the 1-sigma values as a diagonal."""
    D = layout.size
    if covariance is not None and not isinstance(covariance, Mapping):
        cov = np.asarray(covariance, float)
        if cov.shape != (D, D):
            raise RecalInputError(f"coefficient covariance is {cov.shape}, expected ({D}, {D})")
        return 0.5 * (cov + cov.T)
    sigma = np.full(D, np.nan)
    for name, sl in layout.term_slices().items():
        u = coefficients.uncertainty.get(name)
        if u is not None and np.size(u) == sl.stop - sl.start:
            sigma[sl] = u
    if covariance is not None:
        return _named_cov(covariance, layout.names, sigma, notes)
    if not coefficients.uncertainty:
        notes.append(
            "the coefficients carry no 'uncertainty': taken as exact (their own error then "
            "counts as drift)"
        )
    elif np.isnan(sigma).any():
        unknown = [n for n, s in zip(layout.names, sigma, strict=True) if np.isnan(s)]
        notes.append(f"no uncertainty for {', '.join(unknown)}: taken as exact")
    else:
        notes.append(
            "coefficient uncertainty from the file's 1-sigma values as a diagonal covariance "
            "(the file has no 'covariance': their correlations are lost)"
        )
    return np.diag(np.nan_to_num(sigma) ** 2)


def covariance_to_json(names: Sequence[str], covariance: np.ndarray) -> dict[str, Any]:
    """The ``"covariance"`` block a coefficients file carries beside its 1-sigma values."""
    return {
        "names": list(names),
        "matrix": np.asarray(covariance, float).tolist(),
        "kind": "covariance of the flat coefficients (names: term.parameter), units as the "
        "coefficients",
    }


def _named_cov(
    block: Mapping[str, Any], names: Sequence[str], sigma: np.ndarray, notes: list[str]
) -> np.ndarray:
    """The file's covariance reordered to ``names``; coefficients it lacks keep their 1-sigma
    (uncorrelated)."""
    try:
        have = [str(n) for n in block["names"]]
        matrix = np.asarray(block["matrix"], float)
    except (KeyError, TypeError, ValueError):
        raise RecalInputError("'covariance' must have 'names' and a numeric 'matrix'") from None
    if matrix.shape != (len(have), len(have)) or not np.isfinite(matrix).all():
        raise RecalInputError(
            f"'covariance' matrix must be {len(have)} x {len(have)} finite numbers"
        )
    pos = {n: i for i, n in enumerate(have)}
    idx = np.array([pos.get(n, -1) for n in names])
    inside = idx >= 0
    cov = np.diag(np.nan_to_num(sigma) ** 2)
    sub = matrix[np.ix_(idx[inside], idx[inside])]
    cov[np.ix_(inside, inside)] = 0.5 * (sub + sub.T)
    if not inside.all():
        missing = [n for n, ok in zip(names, inside, strict=True) if not ok]
        notes.append(f"the file's covariance lacks {', '.join(missing)}: their 1-sigma used")
    notes.append("coefficient uncertainty from the file's covariance")
    return cov
