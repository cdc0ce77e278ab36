"""What a calibration answers: :class:`CalibrationResult`, with the residuals of each
invariant before and after the fit (:func:`residual_summary`), what its 1-sigma values mean
(:func:`uncertainty_kind`) and its JSON (:func:`result_json`; the result's methods of the same
names call these). The type and its JSON live together so that neither imports the other."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.model.coefficients import CoefficientSet, layout_like
from recal.model.error_model import ParameterLayout
from recal.model.reference import OMEGA_IE_DEG_H
from recal.model.terms import Term
from recal.solve.mcs import MCSResult
from recal.solve.observability import ObservabilityReport
from recal.solve.prior import HeldUncertainty
from recal.solve.problem import Problem

#: The unit of each invariant's residuals (the JSON's residuals.<invariant>.unit).
UNITS = {"gyro_norm": "deg/h", "accel_norm": "g", "dot": "(deg/h)*g", "slew": "rad",
         "rotation": "rad", "closure": "rad"}  # fmt: skip


#: What the Monte Carlo spread means (the JSON's mc.kind): each run on perturbed data ...
MC_KIND = (
    "spread over the Monte Carlo runs, each run fitted to the data perturbed by its window noise "
    "(antithetic pairs): the measurement uncertainty plus the solver's own scatter, a check on "
    "'uncertainty' (the Gauss-Newton 1-sigma, which the product reports)"
)
#: ... or, in paper mode, every run on the same data
MC_KIND_PAPER = (
    "spread over the Monte Carlo runs on the same data: solver repeatability, not measurement "
    "uncertainty (see 'uncertainty')"
)


@dataclass
class CalibrationResult:
    coefficients: CoefficientSet
    status: dict[str, np.ndarray]  # term name -> array of "estimated"/"held"
    uncertainty: dict[str, np.ndarray]  # term name -> 1-sigma (NaN where held)
    covariance: np.ndarray  # (D, D) Gauss-Newton covariance of the flat parameters
    observability: ObservabilityReport
    problem: Problem
    theta: np.ndarray
    theta_prior: np.ndarray
    chi2_red: float
    method: str
    evaluations: int
    wall_time_s: float
    prior_source: str
    mcs: MCSResult | None = None
    notes: list[str] = field(default_factory=list)
    #: the window noise's part of ``covariance`` alone (``covariance`` adds the held part's)
    covariance_measurement: np.ndarray | None = None
    held_uncertainty: HeldUncertainty | None = None
    #: {"converged": bool, "reason": str | None, ...} (recal.solve.convergence)
    convergence: dict[str, Any] = field(default_factory=dict)
    #: what the windows' noise was taken to be: their own sems, and the bias wander between
    #: them (recal.solve.wander) with the test that decided it (JSON-ready)
    noise_model: dict[str, Any] = field(default_factory=dict)
    #: the declared closed turns' 1-sigma, deg (CalibrationOptions.turn_closure_sigma_deg; 0: none)
    turn_closure_declared_deg: float = 0.0

    @property
    def layout(self) -> ParameterLayout:
        return self.problem.layout

    @property
    def terms(self) -> dict[str, Term]:
        return {t.name: t for m in self.problem.models for t in m.terms}

    def residual_summary(self) -> dict[str, Any]:
        return residual_summary(self)

    def uncertainty_kind(self) -> str:
        """What the 1-sigma values mean, and which noise they come from."""
        return uncertainty_kind(self)

    def to_json_dict(self) -> dict[str, Any]:
        return result_json(self)


def residual_summary(result: CalibrationResult) -> dict[str, Any]:
    """The JSON's ``residuals``: per invariant its RMS at the prior and at the fit, the noise
    floor and its source, the seed's eq. 14 indicator, and per-position (slew, turn, rotation)
    residuals."""
    before = result.problem.raw_residuals(result.theta_prior[None])
    after = result.problem.raw_residuals(result.theta[None])
    ind_before = result.problem.indicator(result.theta_prior[None])
    ind_after = result.problem.indicator(result.theta[None])
    out = {}
    for n in result.problem.invariant_names:
        noise = result.problem.noise_known_for(n)
        out[n] = {
            "unit": UNITS[n],
            "reference": _reference_json(result.problem.reference(n)),
            "rms_before": float(np.sqrt(np.mean(before[n] ** 2))),
            "rms_after": float(np.sqrt(np.mean(after[n] ** 2))),
            "noise_floor": float(np.sqrt(np.mean(result.problem.sigma[n] ** 2))) if noise else None,
            "noise_source": result.problem.sigma_source.get(n),
            "indicator_eq14_before": float(ind_before[n][0]),
            "indicator_eq14_after": float(ind_after[n][0]),
            "per_position": [float(v) for v in after[n][0]],
        }
        rows = result.problem.rows_of(n) if n in ("gyro_norm", "accel_norm", "dot") else None
        if rows is not None and len(rows) < result.problem.M:
            # windows left out (accelerometer-only ones; for the dot product also those whose
            # vertical rate is no measurement): name the rows
            out[n]["rows"] = [int(i) for i in rows]
        if n == "rotation":
            out[n]["per_rotation"] = out[n].pop("per_position")
            out[n]["rotations"] = result.problem.n_of(n) // 3
            if noise:
                w = after[n][0] / result.problem.sigma[n]
                out[n]["chi2_red"] = float(np.mean(w * w))
        if n == "closure":
            turns = result.problem.closed_turns
            assert turns is not None
            out[n]["per_turn"] = out[n].pop("per_position")
            out[n]["slews"] = [int(i) for i in turns.index]
            out[n]["turns"] = [int(k) for k in turns.turns]
            out[n]["how"] = [
                c.how for i in turns.index for c in result.problem.turn_candidates if c.slew == i
            ]
            out[n]["closure_sigma_deg"] = [float(v) for v in np.degrees(turns.sigma_rad)]
            if noise:
                w = after[n][0] / result.problem.sigma[n]
                out[n]["chi2_red"] = float(np.mean(w * w))
        if n == "slew":
            out[n]["per_slew"] = out[n].pop("per_position")
            excess = float(result.problem.slew_excess_rad)
            out[n]["unmodelled_excess_rad"] = excess
            if noise and excess > 0:  # the floor above includes it: the windows' own too
                var = np.clip(result.problem.sigma[n] ** 2 - excess**2, 0, None)
                out[n]["window_noise_floor"] = float(np.sqrt(np.mean(var)))
            out[n]["slews"] = result.problem.n_of(n) // 2
            out[n]["earth_rate"] = (
                "removed with the first window's calibrated rest rate"
                if result.problem.slew_earth_rate
                else "left in, as noise (the gyro cannot see Earth rate)"
            )
            if noise:
                w = after[n][0] / result.problem.sigma[n]
                out[n]["chi2_red"] = float(np.mean(w * w))
    return out


def uncertainty_kind(result: CalibrationResult) -> str:
    """What the 1-sigma values mean, and which noise they come from."""
    sources = ", ".join(sorted(set(result.problem.sigma_source.values())))
    held = (
        "; plus what the held coefficients' prior uncertainty moves them by (consider "
        "covariance); a held coefficient's 1-sigma is its prior's"
    )
    if result.problem.noise_known:
        return (
            f"Gauss-Newton 1-sigma from the window noise ({sources}) propagated through the "
            "invariants (scaled by max(1, chi2_red))" + held
        )
    if result.observability.redundancy == 0:
        return "unknown: no noise columns and no redundancy to estimate the noise from"
    return (
        f"Gauss-Newton 1-sigma with the noise estimated from the fit residuals ({sources})" + held
    )


def result_json(result: CalibrationResult) -> dict[str, Any]:
    """``result`` as the calibration JSON (what ``recal calibrate`` writes, and the daemon keeps)."""
    terms = result.terms
    out: dict[str, Any] = {
        "coefficients": result.coefficients.to_json_dict(terms),
        "status": layout_like(result.status, str, terms),
        "uncertainty": layout_like(
            result.uncertainty, lambda v: None if not np.isfinite(v) else float(v), terms
        ),
        "uncertainty_kind": result.uncertainty_kind(),
        "noise_source": dict(result.problem.sigma_source),
        "observability": result.observability.to_json_dict(),
        "residuals": result.residual_summary(),
        "chi2_red": result.chi2_red if np.isfinite(result.chi2_red) else None,
        "method": result.method,
        "sensor": "both" if len(result.problem.sensors) == 2 else result.problem.sensors[0],
        "positions": result.problem.M,
        "latitude_deg": result.problem.latitude_deg,
        "height_m": result.problem.height_m,
        "gravity_g": result.problem.gravity_g,
        "earth_rate_deg_h": OMEGA_IE_DEG_H,
        "prior": result.prior_source,
        "evaluations": result.evaluations,
        "wall_time_s": result.wall_time_s,
        "notes": result.notes,
    }
    if result.noise_model:
        out["noise_model"] = dict(result.noise_model)
    if result.problem.turn_candidates:
        out["turn_closure"] = {
            "declared_sigma_deg": result.turn_closure_declared_deg or None,
            "candidates": [c.to_json_dict() for c in result.problem.turn_candidates],
        }
    if result.convergence:
        out["converged"] = bool(result.convergence.get("converged"))
        out["convergence"] = dict(result.convergence)
    if result.held_uncertainty is not None:
        out["held_uncertainty"] = result.held_uncertainty.to_json_dict()
    if result.mcs is not None:
        split = CoefficientSet.from_vector
        out["mc"] = {
            "runs": int(result.mcs.runs.shape[0]),
            "cycles": result.mcs.cycles,
            "mean": split(result.layout, result.mcs.mean).to_json_dict(terms),
            "std": split(result.layout, result.mcs.std).to_json_dict(terms),
            "kind": MC_KIND_PAPER if result.method.endswith("(paper mode)") else MC_KIND,
        }
    return out


def _reference_json(ref: float | np.ndarray) -> float | list[float]:
    """An invariant's reference: one number, or one per residual where the windows' latitudes
    differ or a gyro norm is taken across gravity (recal.solve.problem.Problem.reference)."""
    a = np.asarray(ref, float)
    if a.ndim == 0 or np.all(a == a.flat[0]):
        return float(a.flat[0]) if a.size else 0.0
    return [float(v) for v in a]
