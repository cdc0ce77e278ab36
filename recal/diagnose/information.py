"""Information gain: how much would new windows sharpen the accepted coefficients? (issue 20)

A recalibration is worth running when the windows that arrived since the accepted version can
improve its answer materially, not because N of them arrived. With the accepted coefficients
theta, their covariance P (a calibration's full covariance: the window noise's part plus what
the held coefficients carry, :mod:`recal.solve.consider`) and the new windows' whitened residual
Jacobian J at theta (the norm, dot-product, slew and closure invariants the engine fits, each
row divided by its own noise, :mod:`recal.solve.problem`), the covariance after adding them is the
linear (Kalman / Fisher) update

    P+ = P - P J^T (J P J^T + I)^-1 J P

written in this form because P may be singular (a coefficient taken as exact) and because a
held coefficient's P is its prior's, so windows that make it observable show as a large gain.
The gain of a coefficient is 1 - sigma+ / sigma; the trigger uses the largest over the watched
coefficients. Repeating the same design N times over gives 1 - sqrt(N / (N + n)) for n new
windows: a gain of 0.2 arrives after about 0.56 N windows, a new orientation or a slew that
shows a held coefficient gives it at once.

This is the linearised gain at the accepted coefficients: the fit that follows can gain less
(its noise re-estimated, windows beyond ``use_last_positions`` dropped) or, where the accepted
coefficients are far from the truth, see more. Pure numerics: no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions

#: Coefficient groups whose sharpening counts (term names' second part), as the drift test's.
WATCH = ("scale", "bias", "misalignment", "quadratic")


@dataclass(frozen=True)
class InformationGain:
    """What adding some windows would do to the accepted coefficients' 1-sigma.

    names: (D,) flat names; sigma_before / sigma_after: (D,) 1-sigma, coefficient units;
    gain: the largest 1 - after / before over the watched coefficients with a known sigma
    (0 when none); coefficient: the name of that coefficient (None when gain is 0).
    """

    names: tuple[str, ...]
    sigma_before: np.ndarray
    sigma_after: np.ndarray
    gain: float
    coefficient: str | None
    windows: int
    slews: int
    notes: tuple[str, ...] = field(default_factory=tuple)

    def relative(self) -> np.ndarray:
        """(D,) 1 - after / before (NaN where before is 0)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.sigma_before > 0, 1.0 - self.sigma_after / self.sigma_before,
                            np.nan)  # fmt: skip

    def to_json_dict(self) -> dict[str, Any]:
        rel = self.relative()
        order = np.argsort(-np.nan_to_num(rel, nan=-1.0))[:5]
        return {
            "gain": round(float(self.gain), 6),
            "coefficient": self.coefficient,
            "windows": self.windows,
            "slews": self.slews,
            "largest": [
                {
                    "name": self.names[i],
                    "sigma_before": float(self.sigma_before[i]),
                    "sigma_after": float(self.sigma_after[i]),
                    "gain": float(rel[i]),
                }
                for i in order
                if np.isfinite(rel[i])
            ],  # fmt: skip
            "notes": list(self.notes),
        }


def posterior_covariance(P: np.ndarray, J: np.ndarray) -> np.ndarray:
    """(D, D) covariance after whitened observations with Jacobian ``J`` (R, D): the Kalman
    update P - P J^T (J P J^T + I)^-1 J P, valid for a singular P."""
    PJt = P @ J.T
    S = J @ PJt + np.eye(J.shape[0])
    out = P - PJt @ np.linalg.solve(S, PJt.T)
    return 0.5 * (out + out.T)


def information_gain(
    positions: Positions,
    coefficients: CoefficientSet,
    covariance: np.ndarray | Mapping[str, Any] | None = None,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    slews: Any = None,
    watch: Sequence[str] = WATCH,
) -> InformationGain:
    """The expected sharpening of ``coefficients`` (covariance as :func:`recal.diagnose.drift.drift_inputs`
    takes it) if ``positions`` (new windows; ``slews`` between them, a :class:`recal.detect.slew_data.Slews`
    in their rows) were added to the data they were fitted on."""
    from recal.diagnose.drift_covariance import coefficient_covariance
    from recal.diagnose.drift_windows import accepted_model
    from recal.solve.observability import jacobian
    from recal.solve.problem import Problem

    if len(positions) == 0:
        raise RecalInputError("no new windows: nothing to gain")
    notes: list[str] = []
    _, models, layout, theta = accepted_model(positions, coefficients, notes)
    problem = Problem.build(positions, models, latitude_deg, height_m, theta, slews=slews)
    if not problem.noise_known:
        raise RecalInputError(
            f"{positions.source}: no window noise columns (*_sem or *_std): the information "
            "of the windows is unknown"
        )
    P = coefficient_covariance(coefficients, layout, covariance, notes)
    typical = layout.typical(theta)
    J = jacobian(problem, theta, np.diag(typical)) / typical  # d(whitened residual)/d theta
    J = np.nan_to_num(J)
    after = posterior_covariance(P, J)
    before_sd = np.sqrt(np.clip(np.diag(P), 0.0, None))
    after_sd = np.sqrt(np.clip(np.diag(after), 0.0, None))
    after_sd = np.minimum(after_sd, before_sd)  # rounding only: information never adds error
    names = tuple(layout.names)
    watched = np.array([n.split(".")[1] in watch for n in names]) & (before_sd > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(watched, 1.0 - after_sd / before_sd, -np.inf)
    best = int(np.argmax(rel)) if rel.size else 0
    gain = float(max(rel[best], 0.0)) if rel.size and np.isfinite(rel[best]) else 0.0
    n_slews = 0 if problem.slews is None else len(problem.slews)
    return InformationGain(
        names, before_sd, after_sd, gain, names[best] if gain > 0 else None,
        len(positions), n_slews, tuple(notes),
    )  # fmt: skip
