"""recal.sim.session: the sample-level session simulator's true inputs, slews, noise and timing."""

import math

import numpy as np
import pytest

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.reference import OMEGA_IE_DEG_H, dot_reference, normal_gravity_g
from recal.sim.session import axis_angle, session_positions, simulate_session
from recal.sim.simulate import NoiseSpec, simulate_positions

RATE = 100.0
QUIET = NoiseSpec(arw_deg_rt_h=0.0, vrw_ug_rt_hz=0.0)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


@pytest.fixture(scope="module")
def quiet_session():
    return simulate_session(
        CoefficientSet.seed_truth(),
        "random",
        12,
        latitude_deg=-33.0,
        seed=4,
        rate_hz=RATE,
        window_s=4.0,
        slew_s=2.0,
        first_hold_s=6.0,
        noise=QUIET,
    )


def test_holds_see_earth_rate_and_gravity_exactly(quiet_session):
    s = quiet_session
    w, f = s.gyro_in_dph[s.static], s.accel_in_g[s.static]
    g = normal_gravity_g(-33.0)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), OMEGA_IE_DEG_H, rtol=1e-13)
    np.testing.assert_allclose(np.linalg.norm(f, axis=1), g, rtol=1e-13)
    np.testing.assert_allclose(np.einsum("ij,ij->i", w, f), dot_reference(-33.0), rtol=1e-12)
    lat = math.radians(-33.0)
    w_n = OMEGA_IE_DEG_H * np.array([0.0, math.cos(lat), math.sin(lat)])
    for k in range(s.n_holds):  # each hold is C_nb^T x_n of its own orientation
        hold = slice(s.hold_first[k], s.hold_last[k] + 1)
        n = hold.stop - hold.start
        w_b = np.broadcast_to(s.orientations[k].T @ w_n, (n, 3))
        f_b = np.broadcast_to(s.orientations[k].T[:, 2] * g, (n, 3))  # C^T [0, 0, g]
        np.testing.assert_allclose(s.gyro_in_dph[hold], w_b, rtol=0, atol=1e-12)
        np.testing.assert_allclose(s.accel_in_g[hold], f_b, rtol=0, atol=1e-15)


def test_timing_and_static_mask(quiet_session):
    s = quiet_session
    assert s.n_holds == 12
    n_hold = s.hold_last - s.hold_first + 1
    assert n_hold[0] == 600 and (n_hold[1:] == 400).all()
    assert (s.hold_first[1:] - s.hold_last[:-1] - 1 == 200).all()  # 2 s slews
    assert len(s) == s.hold_last[-1] + 1 == 600 + 11 * 400 + 11 * 200
    assert s.static.sum() == n_hold.sum()
    np.testing.assert_allclose(s.time_s, np.arange(len(s)) / RATE)
    np.testing.assert_allclose(s.hold_start_s, s.hold_first / RATE)
    assert np.all(np.diff(s.temperature_c) > 0)  # the default 2 degC/h ramp


def test_slews_turn_the_body_smoothly_about_one_axis(quiet_session):
    s = quiet_session
    g = s.gravity_g
    dt = 1.0 / RATE
    f, w = s.accel_in_g, s.gyro_in_dph
    np.testing.assert_allclose(np.linalg.norm(f, axis=1), g, rtol=1e-12)  # a rotation, no lever arm
    w_rad_s = np.radians(w / 3600.0)
    # Kinematics of a navigation-fixed vector seen from the turning body: df/dt = -w x f
    # (the Earth rate part of w is 7e-5 rad/s, far below the tolerance). A sample's rate is the
    # mean over its period, so it is checked at the middle of the period.
    dfdt = (f[1:] - f[:-1]) / dt
    expected = -np.cross(w_rad_s[:-1], 0.5 * (f[1:] + f[:-1]))
    assert np.abs(dfdt - expected).max() < 5e-3 * np.abs(expected).max()
    for k in range(s.n_holds - 1):
        slew = slice(s.hold_last[k] + 1, s.hold_first[k + 1])
        _, angle = axis_angle(s.orientations[k].T @ s.orientations[k + 1])
        turned = np.linalg.norm(w_rad_s[slew], axis=1).sum() * dt  # about a fixed axis
        assert turned == pytest.approx(angle, abs=1e-3)
        # the rate is near zero at both ends (a sample holds the mean over its period): no step
        # into or out of the hold
        peak = np.linalg.norm(w[slew], axis=1).max()
        assert np.linalg.norm(w[slew][0] - w[s.hold_last[k]]) < 0.02 * peak
        peak_rad_s = angle * np.pi / (2 * 2.0)  # raised cosine over 2 s
        assert np.linalg.norm(w_rad_s[slew], axis=1).max() == pytest.approx(peak_rad_s, rel=1e-3)
        assert np.linalg.norm(w_rad_s[slew][-1]) < 0.02 * peak_rad_s  # sin(pi / 200)


def test_axis_angle_round_trip_including_half_turns():
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate(
        (rng.uniform(0, np.pi, 194), [0.0, 1e-9, 1e-4, np.pi - 1e-9, np.pi, np.pi])
    )
    for a, t in zip(axes, angles, strict=True):
        R = _rotation(a, t)
        axis, angle = axis_angle(R)
        assert 0.0 <= angle <= np.pi
        np.testing.assert_allclose(_rotation(axis, angle), R, atol=1e-12)
    for R in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])):
        axis, angle = axis_angle(R)
        assert angle == pytest.approx(np.pi)
        np.testing.assert_allclose(_rotation(axis, angle), R, atol=1e-12)


def test_noise_free_hold_means_match_the_window_mean_simulator():
    truth = CoefficientSet.seed_truth()
    s = simulate_session(
        truth, "24", latitude_deg=50.0, seed=2, rate_hz=20.0, window_s=3.0, slew_s=1.0, noise=QUIET
    )
    means = session_positions(s)
    direct = simulate_positions(truth, "24", latitude_deg=50.0, seed=2, noise=QUIET)
    for name in ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"):
        np.testing.assert_allclose(
            means.columns[name], direct.columns[name], rtol=1e-12, atol=1e-12
        )
    np.testing.assert_allclose(means.columns["samples"], 60)
    np.testing.assert_allclose(means.columns["temperature_rate_c_per_h"], 2.0, rtol=1e-9)


def test_white_noise_has_the_per_sample_sigma():
    truth = CoefficientSet.seed_truth()
    noise = NoiseSpec(arw_deg_rt_h=0.001, vrw_ug_rt_hz=50.0)
    s = simulate_session(truth, "24", seed=1, rate_hz=RATE, window_s=5.0, slew_s=1.0, noise=noise)
    means = session_positions(s)
    at_rate = NoiseSpec(0.001, 50.0, rate_hz=RATE)
    K_g, K_a = truth.values["gyro.scale"], truth.values["accel.scale"]
    std_g = means.stack(("gyro_x_std", "gyro_y_std", "gyro_z_std")).mean(axis=0)
    std_a = means.stack(("accel_x_std", "accel_y_std", "accel_z_std")).mean(axis=0)
    np.testing.assert_allclose(std_g, at_rate.per_sample_sigma("gyro") * K_g, rtol=0.03)
    np.testing.assert_allclose(std_a, at_rate.per_sample_sigma("accel") * K_a, rtol=0.03)


def test_bad_timing_and_oversized_sessions_are_input_errors():
    truth = CoefficientSet.seed_truth()
    with pytest.raises(RecalInputError, match="window_s must be a positive"):
        simulate_session(truth, window_s=0.0)
    with pytest.raises(RecalInputError, match="at least 2 samples"):
        simulate_session(truth, rate_hz=1.0, slew_s=1.0)
    with pytest.raises(RecalInputError, match="samples \\(limit"):
        simulate_session(truth, rate_hz=5000.0, window_s=100.0)
