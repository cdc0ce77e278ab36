"""The acceptance gate on real calibrations of simulated sessions."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import CalibrationOptions, CalibrationResult, calibrate
from service.db import CalibrationRecord
from service.gate import GateConfig, gate

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
