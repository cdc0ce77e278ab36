"""One recalibration job, as it runs in the worker process.

:func:`calibration_job` calibrates the stored positions, predicts what the new coefficients do
to navigation (:func:`navigation_impact_of`, recal.nav.ins_error) and passes the result through the
acceptance gate (service.gate). It returns a picklable :class:`JobOutcome` to the scheduler.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from recal.diagnose.drift_covariance import covariance_to_json
from recal.errors import RecalInputError
from recal.model.positions import Positions
from recal.model.published import calibration_temperature
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
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
    # the temperature it was made at, for the published file (docs/apply.md#the-published-file)
    document["coefficients"].setdefault("metadata", {})["calibration_temperature_c"] = (
        calibration_temperature(columns.get("temperature_c"))
    )
    # the full covariance: the drift and information triggers whiten by it (recal.diagnose.drift)
    document["covariance"] = covariance_to_json(result.layout.names, result.covariance)
    try:
        impact = navigation_impact_of(result, previous, site or {})
    except (RecalInputError, ValueError, np.linalg.LinAlgError) as exc:
        impact = None  # the coefficients stand without it; the document says why it is missing
        document["navigation_impact_error"] = str(exc)
    document["navigation_impact"] = None if impact is None else impact.to_json_dict()
    # the navigator's figures, before and after (docs/navigation.md#heading), and what was held
    prior_name = result.prior_source if options.prior is not None else None
    document["navigation"] = navigation_summary(result, previous, site or {}, impact, prior_name)
    document["held"] = held_at_prior(result)
    check = None
    if options.effects:  # not better than the seed model while its core shift is unconfirmed
        from recal.diagnose.effects import effects_check

        check = effects_check(result, options)
        document["effects_check"] = check
    ageing, label = fleet_ageing(result, options, previous)
    if label is not None:
        document["fleet_prior"] = {**options.fleet_prior.to_json_dict(brief=True),
                                   "months": options.prior_age_months}  # fmt: skip
    decision = gate(result, previous, GateConfig(**gate_settings), impact, check, change_expected,
                    ageing, label)  # fmt: skip
    return JobOutcome(document, decision.accepted, list(decision.reasons))


def months_since(previous: Any, now: datetime | None = None) -> float | None:
    """Months of service (recal.fleet.history.MONTH_DAYS) since the accepted version
    ``previous`` was stored; None without one."""
    from recal.fleet.history import MONTH_DAYS

    if previous is None or previous.created_at is None:
        return None
    then = previous.created_at
    then = then if then.tzinfo is not None else then.replace(tzinfo=UTC)
    days = ((now or datetime.now(UTC)) - then).total_seconds() / 86400.0
    return max(days, 0.0) / MONTH_DAYS


def fleet_ageing(
    result: Any, options: CalibrationOptions, previous: Any
) -> tuple[dict[str, float] | None, str | None]:
    """The gate's ageing allowance (flat name -> 1-sigma change) from the fleet prior over
    the months since ``previous``, and its label; (None, None) without a fleet prior."""
    fleet, months = options.fleet_prior, options.prior_age_months
    if fleet is None or months is None or previous is None:
        return None, None
    names = result.layout.names
    change = fleet.typical_change(names, months, result.theta)
    ageing = {n: float(c) for n, c in zip(names, change, strict=True) if np.isfinite(c)}
    return ageing, f"{fleet.label()} over {months:.3g} months"


def navigation_impact_of(result: Any, previous: Any, site: dict[str, Any]) -> Any:
    """The predicted 24 h static navigation error of a fit, and of replacing ``previous`` (the
    accepted :class:`CalibrationRecord`, or None) by it (:class:`recal.nav.ins_impact.NavigationImpact`).

    Coefficients the fit held keep the accepted version's 1-sigma (they were held at its
    values); a triad the fit did not calibrate is taken from the accepted version.
    """
    from recal.model.coefficients import CoefficientSet
    from recal.nav.ins_impact import complete_seed_set, navigation_impact, seed_covariance
    from recal.nav.ins_uncertainty import predict_from_uncertainty, sigma_from_doc

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


def held_at_prior(result: Any) -> dict[str, dict[str, float | None]]:
    """The coefficients the fit held, by flat name ("gyro.scale.Kz"): the prior's value and
    1-sigma they were held at (the published file carries them: docs/service.md, "Publisher")."""
    names = result.layout.names
    status = np.concatenate([np.asarray(result.status[n]) for n in result.layout.term_slices()])
    held_sigma = result.held_uncertainty.sigma if result.held_uncertainty is not None else None
    out: dict[str, dict[str, float | None]] = {}
    for i in np.flatnonzero(status == "held"):
        sigma = None if held_sigma is None else float(held_sigma[i])
        out[names[i]] = {
            "prior": float(result.theta_prior[i]),
            "prior_sigma": sigma if sigma is not None and np.isfinite(sigma) else None,
        }
    return out


def navigation_summary(
    result: Any,
    previous: Any = None,
    site: dict[str, Any] | None = None,
    impact: Any = None,
    prior_name: str | None = None,
) -> dict[str, Any]:
    """The ``"navigation"`` block of a version and of ``recal calibrate --json``: the
    gyrocompass heading error the horizontal gyro biases leave (:mod:`recal.nav.heading`) and
    the predicted static position error (:func:`navigation_impact_of`), before and after.

    "after" is the fit's uncertainty (the held part included). "before" is ``previous``'s (the
    accepted version: its stored figures), else the prior's 1-sigma the fit started from (the
    prior file ``prior_name``, or the sensor class's defaults without one). ``impact``: the
    fit's :class:`recal.nav.ins_impact.NavigationImpact` against ``previous`` when already
    computed. A figure that cannot be given is replaced by its reason (``*_unavailable``).
    """
    from recal.nav.heading import LEVEL, heading_change, vertical_from_specific_force
    from recal.nav.navigation import NMI_M

    site = site or {}
    lat = float(result.problem.latitude_deg)
    out: dict[str, Any] = {"latitude_deg": lat}
    if previous is not None:
        before_from = f"version {previous.version}"
    elif prior_name:
        before_from = f"the prior {prior_name}"
    else:
        held = result.held_uncertainty
        cls = held.sensor_class if held is not None else "default"
        before_from = f"no prior: the {cls} sensor class's default uncertainty"
    after: dict[str, Any] = {}
    before: dict[str, Any] = {"from": before_from}
    vertical, vertical_from = np.asarray(LEVEL), "level (z vertical)"
    if "accel" in result.problem.sensors:
        f = result.problem.physical(result.theta[None])["accel"][0]
        try:
            vertical, vertical_from = vertical_from_specific_force(f), "the windows' mean gravity"
        except RecalInputError:
            pass
    out["vertical_body"] = [float(v) for v in vertical]
    out["vertical_from"] = vertical_from
    prior_sigma = None if result.held_uncertainty is None else result.held_uncertainty.sigma
    try:
        change = heading_change(result.layout.term_slices(), result.covariance, prior_sigma, lat,
                                vertical)  # fmt: skip
    except RecalInputError as exc:
        out["heading_error_unavailable"] = str(exc)
    else:
        after.update(change.after.to_json_dict())
        stored = _stored_heading(previous)
        if stored is not None:
            before.update(stored)
        elif change.before is not None:
            before.update(change.before.to_json_dict())
    try:
        if previous is None:  # compare with the prior the fit started from
            impact = navigation_impact_of(result, _prior_record(result, before_from), site)
        elif impact is None:
            impact = navigation_impact_of(result, previous, site)
    except (RecalInputError, ValueError, np.linalg.LinAlgError) as exc:
        out["position_error_unavailable"] = str(exc)
    else:
        out["hours"] = impact.hours
        after["position_error_nmi_1sigma"] = impact.error_m_1sigma / NMI_M
        if impact.accepted_error_m_1sigma is not None:
            before["position_error_nmi_1sigma"] = impact.accepted_error_m_1sigma / NMI_M
    out["after"], out["before"] = after, before
    out["summary"] = _navigation_sentence(out)
    return out


def _stored_heading(previous: Any) -> dict[str, Any] | None:
    """The heading figures the accepted version stored for itself (None: it has none)."""
    if previous is None:
        return None
    nav = previous.document.get("navigation") or {}
    after = nav.get("after") if isinstance(nav, dict) else None
    if not isinstance(after, dict) or after.get("heading_error_deg_rms") is None:
        return None
    return {k: v for k, v in after.items() if k.startswith(("heading_", "east_bias_"))}


def _prior_record(result: Any, name: str) -> Any:
    """The prior the fit started from, as a stand-in accepted record: its values and the 1-sigma
    the fit gave them (the prior file's, or the sensor class's defaults)."""
    from types import SimpleNamespace

    from recal.model.coefficients import CoefficientSet, layout_like

    layout, terms = result.layout, result.terms
    prior = CoefficientSet.from_vector(layout, result.theta_prior, result.coefficients.t0_c)
    document: dict[str, Any] = {"coefficients": prior.to_json_dict(terms)}
    if result.held_uncertainty is not None:
        sigma = result.held_uncertainty.sigma
        per_term = {n: sigma[sl] for n, sl in layout.term_slices().items()}
        document["uncertainty"] = layout_like(per_term, float, terms)
    return SimpleNamespace(version=name, document=document)


def _navigation_sentence(nav: dict[str, Any]) -> str:
    """One line: heading error and position error, before -> after."""
    a, b = nav["after"], nav["before"]
    parts = []
    if "heading_error_deg_rms" in a:
        text = (f"gyrocompass heading error {a['heading_error_deg_rms']:.3g} deg RMS over "
                f"headings ({a['heading_error_deg_worst']:.3g} deg at the worst)")  # fmt: skip
        if "heading_error_deg_rms" in b:
            text += f", was {b['heading_error_deg_rms']:.3g} deg"
        parts.append(text)
    if "position_error_nmi_1sigma" in a:
        text = (f"{nav.get('hours', 24):g} h static position error "
                f"{a['position_error_nmi_1sigma']:.2f} nmi")  # fmt: skip
        if "position_error_nmi_1sigma" in b:
            text += f", was {b['position_error_nmi_1sigma']:.2f} nmi"
        parts.append(text)
    if not parts:
        return "no navigation figures for this calibration"
    return "; ".join(parts) + f" (1 sigma, at {nav['latitude_deg']:.1f} deg; before: {b['from']})"
