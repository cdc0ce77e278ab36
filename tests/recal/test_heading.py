"""The gyrocompass heading error a calibration leaves (recal.nav.heading)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.nav.heading import (
    MAX_LATITUDE_DEG,
    heading_change,
    heading_error,
    heading_error_deg,
    horizontal_basis,
    vertical_from_specific_force,
)
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions


def test_an_east_bias_of_0p01_deg_h_at_45_deg_turns_the_heading_0p054_deg() -> None:
    # shared/spec/vessel.md: 0.01 deg/h at 45 deg latitude gives about 0.054 deg (3.2 arcmin)
    assert heading_error_deg(0.01, 45.0) == pytest.approx(0.054, abs=5e-4)
    assert heading_error_deg(0.01, 45.0) * 60 == pytest.approx(3.2, abs=0.05)
    # a level unit whose horizontal biases are both 0.01 deg/h (1 sigma): the same at every heading
    e = heading_error(np.array([0.01, 0.01, 0.5]), 45.0)
    assert e.worst_deg == pytest.approx(0.0539, abs=1e-4)
    assert e.rms_deg == pytest.approx(e.worst_deg, rel=1e-12)
    assert e.east_bias_worst_deg_h == pytest.approx(0.01)  # the vertical bias does not count


def test_the_heading_error_grows_as_one_over_cos_latitude() -> None:
    sigma = np.array([0.01, 0.01, 0.01])
    equator = heading_error(sigma, 0.0).rms_deg
    assert equator == pytest.approx(math.degrees(0.01 / 15.04107), rel=1e-5)
    for lat in (-60.0, 30.0, 60.0, 80.0, 85.0):
        assert heading_error(sigma, lat).rms_deg == pytest.approx(
            equator / math.cos(math.radians(lat)), rel=1e-12
        )
    assert heading_error(sigma, 60.0).rms_deg == pytest.approx(2 * equator, rel=1e-12)


@pytest.mark.parametrize("lat", [85.5, 89.0, 90.0, -88.0])
def test_near_the_poles_the_figure_is_refused_in_one_line(lat: float) -> None:
    with pytest.raises(RecalInputError, match="gyrocompass does not settle") as info:
        heading_error_deg(0.01, lat)
    assert "\n" not in str(info.value) and f"+-{MAX_LATITUDE_DEG:g} deg" in str(info.value)
    with pytest.raises(RecalInputError, match="gyrocompass"):
        heading_error(np.eye(3) * 1e-4, lat)
    with pytest.raises(RecalInputError, match="outside"):
        heading_error_deg(0.01, 91.0)


def test_worst_and_rms_over_headings_match_a_sweep_of_the_heading() -> None:
    # correlated, unequal horizontal biases: the east direction turns with the hull
    cov = np.array([[4e-4, 1.2e-4, 3e-5], [1.2e-4, 1e-4, -2e-5], [3e-5, -2e-5, 9e-4]])
    lat = 52.0
    e = heading_error(cov, lat)
    E = horizontal_basis(None)
    h = np.linspace(0, 2 * np.pi, 3601)[:-1]
    east = np.outer(np.cos(h), E[:, 0]) + np.outer(np.sin(h), E[:, 1])  # (H, 3)
    sd = np.sqrt(np.einsum("hi,ij,hj->h", east, cov, east))
    err = np.degrees(sd / (15.04107 * math.cos(math.radians(lat))))
    assert e.worst_deg == pytest.approx(err.max(), rel=1e-5)
    assert e.rms_deg == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-5)
    assert e.worst_deg > e.rms_deg


def test_the_vertical_axis_decides_which_biases_count() -> None:
    sigma = np.array([0.05, 0.0, 0.0])  # only x is uncertain
    level = heading_error(sigma, 45.0)  # z vertical: x is horizontal and counts
    assert level.worst_deg == pytest.approx(heading_error_deg(0.05, 45.0), rel=1e-12)
    assert level.rms_deg == pytest.approx(level.worst_deg / math.sqrt(2), rel=1e-12)
    x_up = heading_error(sigma, 45.0, vertical=(-1.0, 0.0, 0.0))  # x vertical: it does not
    assert x_up.worst_deg == pytest.approx(0.0, abs=1e-15)
    # z down or z up: the same plane
    assert heading_error(sigma, 45.0, (0, 0, -2)).rms_deg == pytest.approx(level.rms_deg)
    with pytest.raises(RecalInputError, match="vertical axis"):
        heading_error(sigma, 45.0, (0.0, 0.0, 0.0))


def test_the_vertical_comes_from_the_windows_mean_gravity() -> None:
    rng = np.random.default_rng(1)
    tilt = np.radians(0.5) * rng.standard_normal((30, 2))
    f = np.column_stack([tilt[:, 0], tilt[:, 1], -np.ones(30)])  # a level unit, z down
    u = vertical_from_specific_force(f * 9.8)
    assert abs(u[2]) == pytest.approx(1.0, abs=1e-4)
    mounted = vertical_from_specific_force(np.tile([0.0, 0.6, 0.8], (5, 1)))
    assert mounted == pytest.approx([0.0, 0.6, 0.8])
    with pytest.raises(RecalInputError, match="specific force"):
        vertical_from_specific_force(np.zeros((3, 3)))


def test_a_hull_fixed_calibration_cuts_the_heading_error_of_its_prior() -> None:
    """A vessel design with a prior of 0.01 deg/h: after < before, and the fit's horizontal bias
    error lies within 3 of its reported sigmas."""
    truth = CoefficientSet.seed_truth()
    positions = simulate_positions(truth, design="vessel", n_positions=24, latitude_deg=45.0,
                                   seed=3)  # fmt: skip
    prior = truth.copy()
    rng = np.random.default_rng(7)
    prior.values["gyro.bias"] = truth.values["gyro.bias"] + 0.01 * rng.standard_normal(3)
    prior.uncertainty = {n: np.abs(np.asarray(v, float)) * 1e-4 for n, v in truth.values.items()}
    prior.uncertainty["gyro.bias"] = np.full(3, 0.01)
    result = calibrate(positions, CalibrationOptions(latitude_deg=45.0, prior=prior))
    assert result.observability.verdict == "insufficient"  # a hull-fixed unit
    sl = result.layout.term_slices()
    change = heading_change(sl, result.covariance, result.held_uncertainty.sigma, 45.0)
    assert change.before is not None
    assert change.before.rms_deg == pytest.approx(0.0539, abs=1e-4)
    assert change.after.rms_deg < 0.5 * change.before.rms_deg
    err = result.theta[sl["gyro.bias"]][:2] - truth.values["gyro.bias"][:2]
    sd = np.sqrt(np.diag(result.covariance)[sl["gyro.bias"]][:2])
    assert np.all(np.abs(err) < 3 * sd)
    assert "deg RMS over headings" in change.sentence()
