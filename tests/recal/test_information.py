"""The information trigger's expected gain (issue 20, recal.diagnose.information): the Kalman update of
the accepted coefficients' covariance by new windows, checked against the information form, the
repeated-design law 1 - sqrt(N / (N + n)), held coefficients made visible, and slews."""

from __future__ import annotations

import numpy as np
import pytest

from recal.diagnose.information import information_gain, posterior_covariance
from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.sim.session import session_positions, session_slews, simulate_session
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.capture_sim import kvh_like_truth

LAT = 45.0


def test_the_update_is_the_information_form_for_a_regular_prior() -> None:
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    P = A @ A.T + 0.1 * np.eye(6)
    J = rng.normal(size=(20, 6))
    expected = np.linalg.inv(np.linalg.inv(P) + J.T @ J)
    np.testing.assert_allclose(posterior_covariance(P, J), expected, rtol=1e-9, atol=1e-12)
    # a coefficient taken as exact (zero variance) stays exact; nothing else breaks
    P[0, :] = P[:, 0] = 0.0
    after = posterior_covariance(P, J)
    assert abs(after[0, 0]) < 1e-12 and np.all(np.diag(after)[1:] <= np.diag(P)[1:] + 1e-12)


@pytest.fixture(scope="module")
def fit24():
    truth = CoefficientSet.seed_truth()
    pos = simulate_positions(truth, "24", 24, latitude_deg=LAT, seed=5)
    return calibrate(pos, CalibrationOptions(latitude_deg=LAT))


def test_the_same_design_again_gains_what_twice_the_windows_give(fit24) -> None:
    again = simulate_positions(CoefficientSet.seed_truth(), "24", 24, latitude_deg=LAT, seed=6)
    g = information_gain(again, fit24.coefficients, fit24.covariance, LAT)
    rel = g.relative()
    estimated = np.concatenate(
        [np.atleast_1d(fit24.status[t]).ravel() == "estimated" for t in fit24.layout.term_slices()]
    )
    law = 1.0 - np.sqrt(0.5)  # 0.29: the estimated coefficients' sigma falls by 1/sqrt(2)
    # the accepted covariance adds what the held coefficients carry, which new windows of the
    # same design cannot reduce: the estimated ones gain at most the law, most of them near it
    assert np.all(rel[estimated] <= law + 0.03)
    assert np.median(rel[estimated]) > 0.6 * law
    held = ~estimated & (g.sigma_before > 0)
    assert np.all(rel[held] < 0.05), "windows of the same design cannot show a held coefficient"
    assert 0.6 * law < g.gain <= law + 0.03 and g.coefficient is not None
    assert g.windows == 24 and g.slews == 0


def test_a_few_windows_gain_little_and_more_gain_more(fit24) -> None:
    truth = CoefficientSet.seed_truth()
    new = simulate_positions(truth, "24", 24, latitude_deg=LAT, seed=7)
    gains = [
        information_gain(new.subset(np.arange(n)), fit24.coefficients, fit24.covariance, LAT).gain
        for n in (2, 6, 12, 24)
    ]
    assert gains == sorted(gains) and gains[0] < 0.15 < gains[-1]


def test_windows_that_show_a_held_coefficient_gain_at_once() -> None:
    """Faces only (each axis up and down) give the accelerometer's scales and biases and hold
    its misalignments at the prior; tilted windows show them: a gain near 1, whereas the same
    faces again add only noise."""
    truth = CoefficientSet.seed_truth()
    faces = np.array([0, 2, 4, 6, 8, 10, 12, 14])  # of the 24 design: +-x, +-y, +-z up
    acc = ("accel",)
    pos = simulate_positions(truth, "24", 24, latitude_deg=LAT, seed=1, sensors=acc)
    pos = pos.subset(faces)
    fit = calibrate(pos, CalibrationOptions(latitude_deg=LAT, sensor="accel"))
    assert (np.atleast_1d(fit.status["accel.misalignment"]) == "held").any()
    tilted = simulate_positions(truth, "random", 12, latitude_deg=LAT, seed=2, sensors=acc)
    g = information_gain(tilted, fit.coefficients, fit.covariance, LAT)
    rel = g.relative()
    group = np.array([n.split(".")[1] for n in g.names])
    # the quadratic terms, and the biases they made uncertain in the faces' fit (its consider
    # part), are seen at once
    assert g.gain > 0.9 and np.all(rel[group == "quadratic"] > 0.9)
    assert np.all(rel[group == "bias"] > 0.9)
    # a misalignment's symmetric half becomes visible, its antisymmetric half (a rotation of
    # the triad) never is: each sigma falls to 1/sqrt(2) of the prior's, no further
    np.testing.assert_allclose(rel[group == "misalignment"], 1 - np.sqrt(0.5), atol=1e-3)
    again = simulate_positions(truth, "24", 24, latitude_deg=LAT, seed=3, sensors=acc)
    assert information_gain(again.subset(faces), fit.coefficients, fit.covariance, LAT).gain < 0.4


def test_slews_between_the_new_windows_add_their_information() -> None:
    s = simulate_session(kvh_like_truth(7), "random", n_positions=12, latitude_deg=LAT,
                         seed=7, rate_hz=100.0, window_s=8.0, slew_s=3.0)  # fmt: skip
    pos, slews = session_positions(s), session_slews(s)
    fit = calibrate(pos, CalibrationOptions(latitude_deg=LAT, slews=slews))
    s2 = simulate_session(kvh_like_truth(7), "random", n_positions=6, latitude_deg=LAT,
                          seed=8, rate_hz=100.0, window_s=8.0, slew_s=3.0)  # fmt: skip
    new, new_slews = session_positions(s2), session_slews(s2)
    without = information_gain(new, fit.coefficients, fit.covariance, LAT)
    with_slews = information_gain(new, fit.coefficients, fit.covariance, LAT, slews=new_slews)
    assert with_slews.slews == len(new_slews) > 0 and without.slews == 0
    gyro = np.array([n.startswith("gyro.") for n in with_slews.names])
    assert np.all(with_slews.sigma_after[gyro] <= without.sigma_after[gyro] * (1 + 1e-9))
    assert np.any(with_slews.sigma_after[gyro] < 0.95 * without.sigma_after[gyro])


def test_no_windows_or_no_noise_is_an_input_error(fit24) -> None:
    new = simulate_positions(CoefficientSet.seed_truth(), "24", 24, latitude_deg=LAT, seed=6)
    with pytest.raises(RecalInputError, match="no new windows"):
        information_gain(new.subset(np.arange(0)), fit24.coefficients, fit24.covariance, LAT)
    bare = {k: v for k, v in new.columns.items() if not k.endswith(("_std", "_sem"))}
    from recal.model.positions import Positions

    with pytest.raises(RecalInputError):
        information_gain(Positions.from_columns(bare), fit24.coefficients, fit24.covariance, LAT)
