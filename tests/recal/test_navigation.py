"""Strapdown navigation (recal.nav.navigation): accuracy on noiseless data, the linear error model,
decimation and correction."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.nav.ins_static import predict_static_error
from recal.nav.navigation import (
    Decimator,
    attitude_matrix,
    correct_outputs,
    decimate,
    euler_angles,
    navigate,
)
from recal.nav.trajectory import VoyageSpec, simulate_voyage
from recal.sim.simulate import NoiseSpec

LAT = 45.0
NOISELESS = NoiseSpec(0.0, 0.0)


def _static(hours: float, rpy=(0.0, 0.0, 0.0), truth=None, rate=10.0, noise=NOISELESS):
    truth = truth or CoefficientSet.seed_truth()
    v = simulate_voyage(truth, VoyageSpec.static(hours * 3600.0, rpy), LAT, 0.0, 0.0, rate, noise)
    s = v.session
    return truth, decimate(s.time_s, s.gyro_out, s.accel_out, s.temperature_c, rate, 10.0)


def test_true_coefficients_noiseless_static_stays_within_10_m_over_2_h():
    rpy = (2.0, -1.0, 37.0)
    truth, data = _static(2.0, rpy)
    w, f = correct_outputs([truth], data)
    nav = navigate(w, f, 0.1, LAT, 0.0, 0.0, attitude_matrix(*np.radians(rpy)))
    north, east = nav.north_east_error_m(math.radians(LAT), 0.0)
    assert nav.time_s[-1] == pytest.approx(7200.0)
    assert np.hypot(north, east).max() < 10.0
    assert np.degrees(nav.rpy_rad[0, -1]) == pytest.approx(rpy, abs=1e-4)


def test_east_gyro_bias_of_0_01_deg_h_gives_the_linear_model_error():
    """Started at the true attitude (no alignment to hide it), heading 0: body y is east."""
    truth, data = _static(2.0)
    used = truth.copy()
    used.values["gyro.bias"] = truth.values["gyro.bias"] - np.array([0.0, 0.01, 0.0])
    w, f = correct_outputs([used], data)
    nav = navigate(w, f, 0.1, LAT, 0.0, 0.0, np.eye(3), step_s=1.0)
    north, east = nav.north_east_error_m(math.radians(LAT), 0.0)
    pred = predict_static_error(used, truth, LAT, 0.0, (0, 0, 0), hours=2.0, aligned=False)
    nav_h = np.hypot(north[0], east[0])[::60]  # the prediction's 60 s grid
    assert pred.final_m > 1000.0  # km: far above any numerical error
    assert nav_h[-1] == pytest.approx(pred.final_m, rel=0.10)
    assert nav_h.max() == pytest.approx(pred.max_m, rel=0.10)
    assert np.abs(nav_h - pred.horizontal_m).max() < 0.10 * pred.max_m


def test_batched_sets_equal_separate_runs():
    truth, data = _static(0.2)
    other = truth.copy()
    other.values["gyro.bias"] = truth.values["gyro.bias"] + 0.02
    w, f = correct_outputs([truth, other], data)
    both = navigate(w, f, 0.1, LAT, 0.0, 0.0, np.eye(3))
    alone = navigate(w[1], f[1], 0.1, LAT, 0.0, 0.0, np.eye(3))
    np.testing.assert_allclose(both.lat_rad[1], alone.lat_rad[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(both.lon_rad[1], alone.lon_rad[0], rtol=0, atol=1e-15)


def test_voyage_with_true_coefficients_follows_the_truth():
    spec = VoyageSpec(moor_s=60.0)
    truth = CoefficientSet.seed_truth()
    v = simulate_voyage(truth, spec, LAT, 5.0, 0.0, 20.0, NOISELESS)
    s = v.session
    n = round(600 * 20)  # 10 min of it: moored, then the first leg with its acceleration and turn
    data = decimate(s.time_s[:n], s.gyro_out[:n], s.accel_out[:n], None, 20.0, 10.0)
    w, f = correct_outputs([truth], data)
    nav = navigate(w, f, 0.1, LAT, 5.0, 0.0, attitude_matrix(*np.radians(v.rpy_deg[0])))
    idx = np.round(nav.time_s * 20).astype(int)
    north, east = nav.north_east_error_m(np.radians(v.lat_deg[idx]), np.radians(v.lon_deg[idx]))
    assert np.hypot(north, east).max() < 1.0
    assert np.abs(nav.v_ned[0, :, :2] - v.v_ned[idx, :2]).max() < 0.01


def test_decimator_streams_like_bulk_and_keeps_the_grid_over_lost_frames():
    rng = np.random.default_rng(1)
    n = 1000
    t = np.arange(n) / 100.0
    g, a = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    bulk = decimate(t, g, a, None, 100.0, 10.0)
    d = Decimator(100.0, 10)
    for lo in range(0, n, 137):
        d.feed(t[lo : lo + 137], g[lo : lo + 137], a[lo : lo + 137], None)
    np.testing.assert_allclose(d.result().gyro_out, bulk.gyro_out, atol=1e-14)
    assert len(bulk) == 100 and bulk.rate_hz == 10.0
    np.testing.assert_allclose(bulk.gyro_out[3], g[30:40].mean(axis=0))
    # frames 25..34 lost: block 2 averages 20..24, block 3 35..39; time grid unchanged
    keep = np.r_[0:25, 35:n]
    lost = np.zeros(keep.size, np.int64)
    lost[25] = 10
    d = Decimator(100.0, 10)
    d.feed(t[keep], g[keep], a[keep], None, lost_before=lost)
    out = d.result()
    assert len(out) == 100
    np.testing.assert_allclose(out.gyro_out[2], g[20:25].mean(axis=0))
    np.testing.assert_allclose(out.gyro_out[3], g[35:40].mean(axis=0))
    assert out.samples[2] == 5


def test_correction_inverts_the_sensor_model():
    truth, data = _static(0.05, (10.0, 20.0, 30.0))
    w, f = correct_outputs([truth], data)
    C = attitude_matrix(*np.radians((10.0, 20.0, 30.0)))
    lat = math.radians(LAT)
    w_n = 7.2921150e-5 * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    np.testing.assert_allclose(w[0].mean(axis=0), C.T @ w_n, atol=1e-12)
    assert np.linalg.norm(f[0].mean(axis=0)) == pytest.approx(9.80619, abs=1e-4)
    np.testing.assert_allclose(np.degrees(euler_angles(C)), (10.0, 20.0, 30.0), atol=1e-12)
