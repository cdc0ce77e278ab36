"""One recalibration job, as it runs in the worker process.

:func:`calibration_job` calibrates the stored positions, predicts what the new coefficients do
to navigation (:func:`navigation_impact_of`, recal.nav.ins_error) and passes the result through the
acceptance gate (service.gate). It returns a picklable :class:`JobOutcome` to the scheduler.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from recal.diagnose.drift import covariance_to_json
from recal.errors import RecalInputError
from recal.model.positions import Positions
from recal.solve.calibrate import CalibrationOptions, calibrate
from service.jobs import report_progress


@dataclass(frozen=True)
class JobOutcome:
    """What a calibration job returns to the scheduler (picklable)."""

    document: dict[str, Any] | None  # the `recal calibrate --json` object
    accepted: bool
    reasons: list[str]
    error: str | None = None  # unusable design or bad input: wait for more positions


def _mc_progress(options: CalibrationOptions) -> Callable[[float], None] | None:
    """For a swarm method: a progress callback that forwards the Monte Carlo runs done to the
    supervisor (service.jobs.report_progress; the API's /health shows them); None for LM."""
    if options.method == "lm":
        return None
    done = [0.0]

    def progress(runs: float) -> None:
        done[0] += runs
        report_progress(min(done[0], options.mc_runs), options.mc_runs)

    return progress


def calibration_job(
    columns: dict[str, np.ndarray],
    options: CalibrationOptions,
    previous: Any,
    gate_settings: dict[str, Any],
    site: dict[str, Any] | None = None,
    change_expected: str | None = None,
) -> JobOutcome:
    """Calibrate, predict the navigation impact, then gate against the previous accepted
    version. Runs in a worker process. ``site``: ``[site]`` settings (IMU attitude, horizon);
    ``change_expected``: why the coefficients may jump (a declared drift, service.gate)."""
    from service.gate import GateConfig, gate

    try:
        result = calibrate(
            Positions.from_columns(columns, source="store"), options, progress=_mc_progress(options)
        )
    except RecalInputError as exc:
        return JobOutcome(None, False, [str(exc)], error=str(exc))
    document = result.to_json_dict()
    # the full covariance: the drift and information triggers whiten by it (recal.diagnose.drift)
    document["covariance"] = covariance_to_json(result.layout.names, result.covariance)
    try:
        impact = navigation_impact_of(result, previous, site or {})
    except (RecalInputError, ValueError, np.linalg.LinAlgError) as exc:
        impact = None  # the coefficients stand without it; the document says why it is missing
        document["navigation_impact_error"] = str(exc)
    document["navigation_impact"] = None if impact is None else impact.to_json_dict()
    check = None
    if options.effects:  # not better than the seed model while its core shift is unconfirmed
        from recal.diagnose.effects import effects_check

        check = effects_check(result, options)
        document["effects_check"] = check
    decision = gate(result, previous, GateConfig(**gate_settings), impact, check, change_expected)
    return JobOutcome(document, decision.accepted, list(decision.reasons))


def navigation_impact_of(result: Any, previous: Any, site: dict[str, Any]) -> Any:
    """The predicted 24 h static navigation error of a fit, and of replacing ``previous`` (the
    accepted :class:`CalibrationRecord`, or None) by it (:class:`recal.nav.ins_error.NavigationImpact`).

    Coefficients the fit held keep the accepted version's 1-sigma (they were held at its
    values); a triad the fit did not calibrate is taken from the accepted version.
    """
    from recal.model.coefficients import CoefficientSet
    from recal.nav.ins_error import (
        complete_seed_set,
        navigation_impact,
        predict_from_uncertainty,
        seed_covariance,
        sigma_from_doc,
    )

    lat, height = result.problem.latitude_deg, result.problem.height_m
    attitude = tuple(site.get("imu_attitude_rpy_deg", (0.0, 0.0, 0.0)))
    hours = float(site.get("navigation_hours", 24.0))
    old = old_sigma = None
    if previous is not None:
        doc = previous.document
        old = CoefficientSet.from_json_dict(doc.get("coefficients") or {}, source="accepted")
        old_sigma = sigma_from_doc(doc) if doc.get("uncertainty") else {}
    new, _ = complete_seed_set(result.coefficients, old)
    cov, exact = seed_covariance(result.layout.term_slices(), result.covariance, old_sigma)
    accepted_m = None
    if previous is not None:
        old_full, _ = complete_seed_set(old, new)
        stored = previous.document.get("navigation_impact") or {}
        same = [stored.get(k) for k in ("latitude_deg", "hours")] == [lat, hours] and tuple(
            stored.get("attitude_rpy_deg") or ()
        ) == attitude
        if same and stored.get("static_24h_error_m_1sigma") is not None:
            accepted_m = float(stored["static_24h_error_m_1sigma"])
        elif old_sigma:  # an older record, or the site changed: recompute (independent 1-sigmas)
            u = predict_from_uncertainty(previous.document, old_full, lat, height, attitude, hours)
            accepted_m = float(u.sigma_horizontal_m[-1])
        old = old_full
    return navigation_impact(
        new, cov, lat, height, attitude, hours, exact, old,
        None if previous is None else previous.version, accepted_m,
    )  # fmt: skip
