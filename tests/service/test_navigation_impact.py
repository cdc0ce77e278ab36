"""Every calibration version carries its predicted navigation impact; the gate may use it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.nav.ins_impact import complete_seed_set, seed_covariance
from recal.nav.ins_static import predict_static_error
from recal.nav.ins_uncertainty import predict_from_uncertainty
from recal.nav.navigation import NMI_M
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.gate import GateConfig
from service.recalibration import calibration_job, navigation_impact_of
from service.store.records import CalibrationRecord

TRUTH = CoefficientSet.seed_truth()
LAT = 52.0
SITE = {"imu_attitude_rpy_deg": (0.0, 0.0, 30.0), "navigation_hours": 24.0}


def _job(positions: Any, previous: CalibrationRecord | None, **gate: Any) -> Any:
    options = CalibrationOptions(latitude_deg=LAT)
    settings = GateConfig(**gate).__dict__
    return calibration_job(positions.columns, options, previous, settings, SITE)


@pytest.fixture(scope="module")
def accepted() -> CalibrationRecord:
    """Version 6: a 36-position random design, accepted, with its impact stored."""
    positions = simulate_positions(
        TRUTH, design="random", n_positions=36, latitude_deg=LAT, seed=11
    )
    outcome = _job(positions, None)
    assert outcome.accepted, outcome.reasons
    return CalibrationRecord(
        version=6, trigger="auto", method="lm", accepted=True, document=outcome.document
    )


def test_a_version_stores_the_error_its_uncertainty_allows() -> None:
    positions = simulate_positions(TRUTH, design="24", latitude_deg=LAT, seed=4)
    outcome = _job(positions, None)
    impact = outcome.document["navigation_impact"]
    assert impact["change"] is None and impact["hours"] == 24.0
    assert impact["attitude_rpy_deg"] == [0.0, 0.0, 30.0]
    # the same figure as the engine's prediction from the fit's full covariance
    result = calibrate(positions, CalibrationOptions(latitude_deg=LAT))
    cov, exact = seed_covariance(result.layout.term_slices(), result.covariance)
    full, _ = complete_seed_set(result.coefficients)
    u = predict_from_uncertainty(None, full, LAT, 0.0, (0, 0, 30), covariance=cov)
    assert impact["static_24h_error_nmi_1sigma"] == pytest.approx(u.final_nmi, rel=1e-9)
    assert impact["counted_as_exact"] == exact
    assert "allows a 24 h static error of" in impact["summary"]


def test_the_change_from_the_accepted_version_is_the_linear_prediction(
    accepted: CalibrationRecord,
) -> None:
    positions = simulate_positions(TRUTH, design="24", latitude_deg=LAT, seed=5)
    outcome = _job(positions, accepted)
    change = outcome.document["navigation_impact"]["change"]
    assert change["from_version"] == 6
    old = CoefficientSet.from_json_dict(accepted.document["coefficients"])
    new = CoefficientSet.from_json_dict(outcome.document["coefficients"])
    p = predict_static_error(old, new, LAT, 0.0, (0, 0, 30))
    assert change["old_error_nmi"] == pytest.approx(p.final_nmi, rel=1e-9)
    stored = accepted.document["navigation_impact"]["static_24h_error_nmi_1sigma"]
    assert change["accepted_error_nmi_1sigma"] == pytest.approx(stored)
    assert change["delta_nmi"] == pytest.approx(change["new_error_nmi"] - change["old_error_nmi"])
    # the gate's notes carry the sentence a navigation officer reads
    assert any(r.startswith("loading this version instead of version 6") for r in outcome.reasons)


def test_the_gate_can_refuse_a_version_that_predicts_a_worse_error(
    accepted: CalibrationRecord,
) -> None:
    # 10 positions instead of 36: a consistent, but far less certain, calibration
    few = simulate_positions(TRUTH, design="random", n_positions=10, latitude_deg=LAT, seed=12)
    lenient = _job(few, accepted)
    strict = _job(few, accepted, refuse_worse_navigation=True)
    new = lenient.document["navigation_impact"]["static_24h_error_nmi_1sigma"]
    old = accepted.document["navigation_impact"]["static_24h_error_nmi_1sigma"]
    assert new > old
    assert lenient.accepted, lenient.reasons  # off by default
    assert not strict.accepted
    assert any("(refuse_worse_navigation)" in r for r in strict.reasons), strict.reasons
    # a margin larger than the difference lets it through
    margin = _job(
        few, accepted, refuse_worse_navigation=True, navigation_margin_nmi=new - old + 0.1
    )
    assert margin.accepted, margin.reasons


def test_held_coefficients_keep_the_accepted_versions_uncertainty(
    accepted: CalibrationRecord,
) -> None:
    # eight positions: the accelerometer quadratic terms are held at the prior
    positions = simulate_positions(TRUTH, design="random", n_positions=8, latitude_deg=LAT, seed=3)
    alone = calibrate(positions, CalibrationOptions(latitude_deg=LAT))
    assert (alone.status["accel.quadratic"] == "held").all()
    # without a prior file they carry the sensor class's default, not zero
    assert alone.held_uncertainty is not None
    assert alone.held_uncertainty.sensor_class == "navigation"
    np.testing.assert_allclose(alone.uncertainty["accel.quadratic"], 5e-5, rtol=1e-9)
    assert navigation_impact_of(alone, None, SITE).exact == ()
    # held at the accepted version: its 1-sigma, carried into the fit's covariance
    prior = CoefficientSet.from_json_dict(accepted.document["coefficients"])
    kept = accepted.document["uncertainty"]["accel"]["quadratic"]
    with_prior = calibrate(positions, CalibrationOptions(latitude_deg=LAT, prior=prior))
    assert (with_prior.status["accel.quadratic"] == "held").all()
    np.testing.assert_allclose(with_prior.uncertainty["accel.quadratic"], kept, rtol=1e-9)
    assert navigation_impact_of(with_prior, accepted, SITE).exact == ()


def test_an_older_record_without_an_impact_is_recomputed(
    accepted: CalibrationRecord, make_record: Callable[..., CalibrationRecord]
) -> None:
    doc = {k: v for k, v in accepted.document.items() if k != "navigation_impact"}
    old = make_record(version=2, document=doc)
    positions = simulate_positions(TRUTH, design="24", latitude_deg=LAT, seed=6)
    result = calibrate(positions, CalibrationOptions(latitude_deg=LAT))
    impact = navigation_impact_of(result, old, SITE)
    assert impact.from_version == 2
    # from the independent 1-sigmas: close to, not equal to, the full-covariance figure
    stored = accepted.document["navigation_impact"]["static_24h_error_m_1sigma"]
    assert impact.accepted_error_m_1sigma is not None
    assert 0.2 < impact.accepted_error_m_1sigma / stored < 5
    assert np.isfinite(impact.error_m_1sigma / NMI_M)


def test_a_version_carries_heading_and_position_error_before_and_after(
    accepted: CalibrationRecord,
) -> None:
    """``navigation``: after from the version's own uncertainty, before from the accepted version
    it replaces (its stored figures), or from the prior for the first one."""
    first = accepted.document["navigation"]
    assert first["before"]["from"].startswith("no prior: the navigation sensor class's default")
    impact = accepted.document["navigation_impact"]
    assert first["after"]["position_error_nmi_1sigma"] == pytest.approx(
        impact["static_24h_error_nmi_1sigma"], rel=1e-9
    )
    before, after = first["before"], first["after"]
    assert before["position_error_nmi_1sigma"] > after["position_error_nmi_1sigma"]
    assert after["heading_error_deg_rms"] < before["heading_error_deg_rms"]
    positions = simulate_positions(TRUTH, design="24", latitude_deg=LAT, seed=5)
    nav = _job(positions, accepted).document["navigation"]
    assert nav["before"]["from"] == "version 6"
    for key in ("heading_error_deg_rms", "heading_error_deg_worst", "east_bias_deg_h_rms"):
        assert nav["before"][key] == first["after"][key]
    assert nav["before"]["position_error_nmi_1sigma"] == pytest.approx(
        impact["static_24h_error_nmi_1sigma"], rel=1e-9
    )
    assert nav["latitude_deg"] == LAT and nav["hours"] == 24.0
    assert nav["summary"].startswith("gyrocompass heading error ")
    assert "before: version 6" in nav["summary"]
