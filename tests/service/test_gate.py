"""The acceptance gate on real calibrations of simulated sessions."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from recal.solve.result import CalibrationResult
from service.gate import GateConfig, gate
from service.store.records import CalibrationRecord

TRUTH = CoefficientSet.seed_truth()


def run(truth: CoefficientSet = TRUTH, seed: int = 2, latitude: float = 45.0) -> CalibrationResult:
    positions = simulate_positions(truth, seed=seed, latitude_deg=45.0)
    return calibrate(positions, CalibrationOptions(latitude_deg=latitude))


@pytest.fixture
def previous(make_record: Callable[..., CalibrationRecord]) -> CalibrationRecord:
    """Version 3: the calibration_result fixture (seed 1), accepted."""
    return make_record(version=3)


@pytest.fixture(scope="module")
def jumped() -> CalibrationResult:
    """The gyro x scale factor grew by 0.2 % (about 18 combined sigma)."""
    truth = TRUTH.copy()
    truth.values["gyro.scale"] = truth.values["gyro.scale"] * np.array([1.002, 1.0, 1.0])
    return run(truth, seed=3)


def test_first_calibration_is_accepted(calibration_result: CalibrationResult) -> None:
    decision = gate(calibration_result, None)
    assert decision.accepted
    assert decision.reasons == ["no accepted calibration yet: nothing to compare against"]


def test_a_consistent_recalibration_is_accepted(previous: CalibrationRecord) -> None:
    decision = gate(run(seed=2), previous, GateConfig())
    assert decision.accepted, decision.reasons
    assert decision.reasons[0].startswith("largest change from version 3:")


def test_a_jump_is_rejected_with_the_coefficient_named(
    jumped: CalibrationResult, previous: CalibrationRecord
) -> None:
    decision = gate(jumped, previous)
    assert not decision.accepted
    assert len(decision.reasons) == 1
    reason = decision.reasons[0]
    assert reason.startswith("gyro.scale.Kx moved ") and reason.endswith(
        " sigma from version 3 (limit 6)"
    )
    assert float(reason.split()[2]) > 10


def test_allow_jump_accepts_but_says_so(
    jumped: CalibrationResult, previous: CalibrationRecord
) -> None:
    decision = gate(jumped, previous, GateConfig(allow_jump=True))
    assert decision.accepted
    assert decision.reasons[0].startswith("gyro.scale.Kx moved ")
    assert decision.reasons[0].endswith("allowed (allow_jump)")


def test_held_coefficients_are_not_compared(
    jumped: CalibrationResult, previous: CalibrationRecord
) -> None:
    status = dict(jumped.status)
    status["gyro.scale"] = np.array(["held", "estimated", "estimated"])
    assert gate(dataclasses.replace(jumped, status=status), previous).accepted


def test_a_wrong_latitude_is_rejected_by_chi2(previous: CalibrationRecord) -> None:
    decision = gate(run(seed=4, latitude=55.0), previous)
    assert not decision.accepted
    assert decision.reasons[0].startswith("chi2_red ")
    assert "exceeds 4: the residuals exceed the window noise" in decision.reasons[0]


def test_an_insufficient_design_is_rejected(calibration_result: CalibrationResult) -> None:
    # recal.solve.calibrate itself refuses insufficient designs; the gate must still hold the line.
    report = dataclasses.replace(
        calibration_result.observability,
        verdict="insufficient",
        message="scale and bias of gyro z cannot be separated",
    )
    decision = gate(dataclasses.replace(calibration_result, observability=report), None)
    assert not decision.accepted
    assert decision.reasons == [
        "observability verdict is insufficient (scale and bias of gyro z cannot be separated); "
        "partial or better is required"
    ]


def test_require_full_rejects_a_partial_design(calibration_result: CalibrationResult) -> None:
    assert calibration_result.observability.verdict == "partial"  # norms never see rotations
    decision = gate(calibration_result, None, GateConfig(require_verdict="full"))
    assert not decision.accepted
    assert decision.reasons[0].startswith("observability verdict is partial")


def test_a_poorly_determined_scale_is_rejected(calibration_result: CalibrationResult) -> None:
    decision = gate(calibration_result, None, GateConfig(max_relative_scale_sigma=1e-7))
    assert not decision.accepted
    assert decision.reasons[0].startswith("gyro.scale.Kx 1-sigma is ")
    assert decision.reasons[0].endswith(" of its value (limit 1e-07)")
    assert len(decision.reasons) == 6  # three gyro and three accel scale factors


def test_bad_config_is_refused() -> None:
    with pytest.raises(ValueError, match="require_verdict"):
        GateConfig(require_verdict="insufficient")


@pytest.fixture(scope="module")
def hull_fixed() -> CalibrationResult:
    """A hull-fixed unit (vessel design: heading turns, small tilts) with a good prior: the
    vertical gyro scale and the accel scales cannot be told from their biases."""
    prior = TRUTH.copy()
    prior.uncertainty = {n: np.abs(np.asarray(v, float)) * 1e-4 + 1e-5
                         for n, v in TRUTH.values.items()}  # fmt: skip
    prior.uncertainty["gyro.bias"] = np.full(3, 0.01)
    positions = simulate_positions(TRUTH, design="vessel", n_positions=24, seed=5)
    return calibrate(positions, CalibrationOptions(latitude_deg=45.0, prior=prior))


def test_a_hull_fixed_fit_is_rejected_by_default(hull_fixed: CalibrationResult) -> None:
    assert hull_fixed.observability.verdict == "insufficient"
    decision = gate(hull_fixed, None)
    assert not decision.accepted
    assert decision.reasons[0].startswith("observability verdict is insufficient (")
    assert decision.reasons[0].endswith("partial or better is required")


def test_publish_observable_part_accepts_it_naming_the_held_coefficients(
    hull_fixed: CalibrationResult, previous: CalibrationRecord
) -> None:
    cfg = GateConfig(publish_observable_part=True)
    held = [f"{t}.{p}" for t, st in hull_fixed.status.items()
            for p, s in zip(hull_fixed.terms[t].params, st, strict=True) if s == "held"]  # fmt: skip
    assert "gyro.scale.Kz" in held and "accel.scale.Kx" in held
    for prev in (None, previous):
        decision = gate(hull_fixed, prev, cfg)
        assert decision.accepted, decision.reasons
        note = next(r for r in decision.reasons if "publish_observable_part" in r)
        assert note.startswith("observability verdict is insufficient (")
        assert note.endswith(f"{len(held)} coefficient(s) held at the prior: {', '.join(held)}")
    # every other limit still applies
    strict = GateConfig(publish_observable_part=True, max_relative_scale_sigma=1e-9)
    decision = gate(hull_fixed, None, strict)
    assert not decision.accepted and decision.reasons[0].startswith("gyro.scale.Kx 1-sigma")
    # require_verdict = "full" wins: the setting lets insufficient count as partial, no more
    assert not gate(hull_fixed, None, GateConfig(publish_observable_part=True,
                                                 require_verdict="full")).accepted  # fmt: skip


def test_publish_observable_part_needs_something_estimated(hull_fixed: CalibrationResult) -> None:
    status = {n: np.full(s.shape, "held") for n, s in hull_fixed.status.items()}
    nothing = dataclasses.replace(hull_fixed, status=status)
    decision = gate(nothing, None, GateConfig(publish_observable_part=True))
    assert not decision.accepted
    assert decision.reasons[0].endswith(
        "nothing is estimated, so there is no observable part to publish"
    )


# ---- the fleet prior (issue 28): a unit started from its model's ageing -------------------------
def _fleet_of_fast_ageing_accelerometers(tmp_path):
    """A simulated fleet whose accel biases age 15 ug per sqrt-month (about 50 ug a year: far
    beyond the 2 ug a version's own 1-sigma allows without ageing), the rest at the size of
    their measurement errors; its prior saved and read back as the vessel does."""
    from recal import fleet_prior, simulate_fleet
    from recal.fleet.history import is_relative
    from service.startup import read_fleet_prior_file, write_fleet_prior_file

    first = calibrate(simulate_positions(TRUTH, seed=1))
    names, theta = first.layout.names, first.theta
    sigma = np.sqrt(np.diag(first.covariance))
    rel = np.array([is_relative(n) for n in names])
    rates = np.where(rel, sigma / np.abs(theta), sigma)
    rates = np.where([n.startswith("accel.bias.") for n in names], 15e-6, rates)
    fleet = simulate_fleet(names, theta, rates, sigma, units=200, years=5.0, seed=4242)
    path = tmp_path / "fleet_prior.json"
    write_fleet_prior_file(str(path), fleet_prior(fleet.versions, "KVH-1750", version=2))
    return read_fleet_prior_file(str(path)), first, path


def test_a_unit_started_from_the_fleet_prior_passes_its_first_recalibration(tmp_path) -> None:
    """Six months after commissioning the accel x bias has aged 25 ug (about 0.7 sigma of its
    model's ageing): without the fleet prior the gate allows no ageing and rejects the unit's
    first recalibration; with it, the fleet's change over the months is allowed and the
    version records which prior it used."""
    from datetime import UTC, datetime, timedelta

    from service.config import GateSettings
    from service.recalibration import calibration_job, months_since

    prior, first, path = _fleet_of_fast_ageing_accelerometers(tmp_path)
    got = prior.coefficients["accel.bias.bx"]
    assert abs(got.rate / 15e-6 - 1.0) < 0.2
    commissioned = CalibrationRecord(
        version=1, created_at=datetime.now(UTC) - timedelta(days=182.6), trigger="manual",
        method="lm", accepted=True, document=first.to_json_dict(),
    )  # fmt: skip
    aged = TRUTH.copy()
    aged.values["accel.bias"] = aged.values["accel.bias"] + np.array([25e-6, -10e-6, 5e-6])
    positions = simulate_positions(aged, seed=2)
    months = months_since(commissioned)
    assert months == pytest.approx(6.0, abs=0.01)

    def job(fleet):
        options = CalibrationOptions(prior=None, fleet_prior=fleet, prior_age_months=months)
        settings = GateSettings(fleet_prior=None if fleet is None else str(path))
        return calibration_job(positions.columns, options, commissioned, settings.model_dump())

    datasheet = job(None)
    assert not datasheet.accepted
    assert any(r.startswith("accel.bias.bx moved ") for r in datasheet.reasons), datasheet.reasons
    fleet = job(prior)
    assert fleet.accepted, fleet.reasons
    assert "ageing allowed: fleet prior KVH-1750 v2" in fleet.reasons[0]
    assert fleet.document["fleet_prior"] == {**prior.to_json_dict(brief=True), "months": months}
    # a version that jumped far beyond the fleet's ageing is still refused
    broken = TRUTH.copy()
    broken.values["accel.bias"] = broken.values["accel.bias"] + np.array([900e-6, 0.0, 0.0])
    positions = simulate_positions(broken, seed=2)
    assert not job(prior).accepted


def test_the_fleet_prior_setting_refuses_a_newer_format_at_start(tmp_path) -> None:
    import json

    from recal.errors import RecalInputError
    from service.startup import read_fleet_prior_file

    path = tmp_path / "p.json"
    path.write_text(json.dumps({"format": "recal.fleet_prior/9", "version": 1}))
    with pytest.raises(RecalInputError, match=r"\[gate\] fleet_prior: .*p.json: format "
                       r"recal.fleet_prior/9 is newer than this recal reads"):  # fmt: skip
        read_fleet_prior_file(str(path))


def test_the_scheduler_gives_its_jobs_the_fleet_prior_and_the_months(tmp_path, document) -> None:
    """``[gate] fleet_prior`` reaches every job with the months since the current version."""
    from datetime import UTC, datetime, timedelta
    from types import SimpleNamespace

    from recal.fleet.prior import CoefficientAgeing, FleetPrior
    from service.config import load_settings
    from service.scheduler import Scheduler
    from service.startup import write_fleet_prior_file
    from service.store.repository import Store

    path = tmp_path / "fleet.json"
    figure = CoefficientAgeing(1e-5, 1e-6, False, 50, 400)
    write_fleet_prior_file(str(path), FleetPrior("KVH-1750", 5, "2026-11-01T00:00:00Z",
                                                 {"accel.bias.bx": figure}))  # fmt: skip
    settings = load_settings(gate={"fleet_prior": str(path)}, scheduler={"use_slews": False})
    store = Store(f"sqlite:///{tmp_path / 'recal.db'}")
    store.create_schema()
    seed = TRUTH.values
    unit = {n: np.ones(3) if n.endswith("scale") else np.zeros_like(v) for n, v in seed.items()}
    positions = simulate_positions(CoefficientSet(unit), seed=1)  # a KVH: deg/h and g
    store.add_positions(store.add_session("test"), positions.columns)
    store.add_calibration(CalibrationRecord(
        created_at=datetime.now(UTC) - timedelta(days=91.3), trigger="manual", method="lm",
        accepted=True, document=document,
    ))  # fmt: skip
    submitted = []
    runner = SimpleNamespace(busy=False, submit=lambda fn, args, on_end: submitted.append(args))
    events = SimpleNamespace(emit=lambda *a, **k: None)
    Scheduler(store, settings, None, events=events, runner=runner).trigger("manual")
    (args,) = submitted
    assert args[1].fleet_prior.version == 5
    assert args[1].prior_age_months == pytest.approx(3.0, abs=0.01)
    assert args[3]["fleet_prior"] == str(path)
