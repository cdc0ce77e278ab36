"""MCS-NAFSA with slews (issue 19): the linearised slew invariant, runs on perturbed data, and
agreement with LM. No timing here: benchmarks/bench_mcs_slews.py measures the speed."""

from __future__ import annotations

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from recal.solve.surrogate import SurrogateProblem, data_noise


@pytest.fixture
def session_data(slew_session):
    return slew_session


@pytest.fixture
def lm(slew_lm):
    return slew_lm


def test_the_surrogate_is_the_exact_objective_at_its_reference_and_close_nearby(lm):
    problem, theta = lm.problem, lm.theta
    assert "slew" in problem.invariant_names
    typical = problem.layout.typical(theta)
    sur = SurrogateProblem.at(problem, theta, typical)
    exact = problem.objective(theta[None])
    np.testing.assert_allclose(sur.objective(theta[None]), exact, rtol=1e-9)
    # 3 sigma away along every estimated direction: the linearised slews stay within 1 % of
    # the exact objective's rise (they are nearly linear over a few sigma)
    sd = np.sqrt(np.diag(lm.covariance_measurement))
    rng = np.random.default_rng(0)
    away = theta + 3.0 * sd * rng.choice([-1.0, 1.0], size=(20, theta.size))
    rise_exact = problem.objective(away) - exact
    rise_sur = sur.objective(away) - exact
    assert np.all(rise_exact > 0)
    np.testing.assert_allclose(rise_sur, rise_exact, rtol=1e-2)
    # the phase objective (quadratic form per run) is the same function in phase coordinates
    noise = data_noise(problem, 4, rng)
    sur = SurrogateProblem.at(problem, theta, typical, noise)
    base = theta + 0.5 * sd * rng.normal(size=(4, theta.size))
    T = typical[:, None] * lm.observability.basis
    X = rng.normal(size=(10, T.shape[1]))
    run = np.arange(10) % 4
    np.testing.assert_allclose(
        sur.phase_objective(base, T)(X, run), sur.objective(base[run] + X @ T.T, run), rtol=1e-9
    )


def test_data_noise_comes_in_antithetic_pairs_of_the_window_noise(lm):
    problem = lm.problem
    noise = data_noise(problem, 5, np.random.default_rng(1))
    for name, offsets in noise.items():
        assert offsets.shape == (5, problem.n_of(name))
        np.testing.assert_array_equal(offsets[0], -offsets[1])
        np.testing.assert_array_equal(offsets[2], -offsets[3])
    # the slew residuals are perturbed by their own 1-sigma (linear invariant)
    z = noise["slew"][0::2] / problem.sigma["slew"]
    assert 0.5 < z.std() < 1.5


def test_nafsa_with_slews_agrees_with_lm_and_its_spread_estimates_lm_sigma(
    session_data, lm, slew_latitude
):
    pos, slews = session_data
    opt = CalibrationOptions(method="nafsa", mc_runs=40, seed=3, latitude_deg=slew_latitude,
                             slews=slews)  # fmt: skip
    done: list[float] = []
    res = calibrate(pos, opt, progress=done.append)
    assert "slew" in res.problem.invariant_names and res.mcs.runs.shape[0] == 40
    est = lm.observability.estimated
    np.testing.assert_array_equal(res.observability.estimated, est)
    sd = np.sqrt(np.diag(lm.covariance_measurement))[est]
    # the MC mean within 1 LM sigma of LM's estimate (median well inside it)
    z = np.abs(res.theta - lm.theta)[est] / sd
    assert np.median(z) < 0.5 and np.all(z < 1.0)
    # every run fits its own perturbed data: the spread estimates LM's sigma (40 runs: the
    # std itself scatters by ~11 %)
    ratio = res.mcs.std[est] / sd
    assert 0.67 < np.median(ratio) < 1.5
    assert "perturbed by its window noise" in res.to_json_dict()["mc"]["kind"]
    # progress: the runs done, reported as the batch goes through its cycles
    assert len(done) > 1 and sum(done) == pytest.approx(40)


def test_forked_workers_report_progress_as_they_go():
    pos = simulate_positions(CoefficientSet.seed_truth(), "random", 24, 30.0, seed=11,
                             sensors=("gyro",))  # fmt: skip
    done: list[float] = []
    opt = CalibrationOptions(sensor="gyro", latitude_deg=30.0, method="nafsa", mc_runs=60)
    calibrate(pos, opt, progress=done.append)  # two batches: forked workers on two cores
    assert sum(done) == pytest.approx(60) and all(d > 0 for d in done)
