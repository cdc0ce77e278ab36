"""Issue 25, items 4 and 5 (calibrate side): held means held, no absurd answer, many windows.

A hull-fixed IMU (z up, small tilts, headings vary) shows near-coplanar gravity: the vertical
axes' scale factor and bias cannot be told apart. With a good prior the coefficients it cannot
see stand exactly at the prior and everything it reports covers the truth; without one it gives
a clear partial result, never the accelerometer scale factors of 1e-5 and vertical bias of
141,262 g the data-derived ellipsoid start once led to.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import recal.solve.start as start
from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model, ParameterLayout
from recal.sim.session import session_positions, session_slews, simulate_session
from recal.sim.simulate import NoiseSpec, simulate_positions
from recal.solve.believable import unbelievable
from recal.solve.calibrate import LM_STEPS, calibrate
from recal.solve.options import CalibrationOptions
from recal.solve.start import common_start, data_prior, references
from service.cli.main import main

LAT = 45.0
#: The issue's good prior: 100 ppm of scale, 0.01 deg/h of gyro bias, 20 ug of accel bias
#: (misalignment 0.1 mrad, quadratic 1e-5 /g), with that uncertainty in the file.
PRIOR_SIGMA = {
    "gyro.scale": 1e-4, "gyro.bias": 0.01, "gyro.misalignment": 1e-4,
    "accel.scale": 1e-4, "accel.bias": 2e-5, "accel.misalignment": 1e-4, "accel.quadratic": 1e-5,
}  # fmt: skip


def _prior_near(truth: CoefficientSet, rng: np.random.Generator) -> CoefficientSet:
    """The truth moved by a draw from PRIOR_SIGMA, carrying that uncertainty."""
    prior = truth.copy()
    for name, s in PRIOR_SIGMA.items():
        v = truth.values[name]
        sigma = s * np.abs(v) if name.endswith(".scale") else np.full(v.shape, s)
        prior.values[name] = v + sigma * rng.normal(size=v.shape)
        prior.uncertainty[name] = sigma
    prior.metadata["source"] = "previous calibration"
    return prior


def _core(names: list[str]) -> np.ndarray:
    return np.array([".scale." in n or ".bias." in n for n in names])


@pytest.mark.parametrize("seed", range(5))
def test_held_coefficients_stand_at_the_prior_and_estimated_ones_cover_the_truth(seed):
    truth = CoefficientSet.seed_truth()
    prior = _prior_near(truth, np.random.default_rng(200 + seed))
    pos = simulate_positions(truth, "vessel", 24, LAT, seed=seed)
    res = calibrate(pos, CalibrationOptions(latitude_deg=LAT, prior=prior))
    names = res.layout.names
    held = ~res.observability.estimated
    # the vertical gyro scale factor cannot be told from the vertical bias: held, exactly
    assert held[names.index("gyro.scale.Kz")] and not held[names.index("gyro.bias.bz")]
    np.testing.assert_array_equal(res.theta[held], prior.to_vector(res.layout)[held])
    status = res.to_json_dict()["status"]
    assert status["gyro"]["scale"][2] == "held"
    for sensor in ("gyro", "accel"):  # the JSON says held exactly where the value is the prior
        for term in ("scale", "bias"):
            got = np.array(res.to_json_dict()["coefficients"][sensor][term])
            at_prior = got == prior.values[f"{sensor}.{term}"]
            assert list(at_prior) == [s == "held" for s in status[sensor][term]]
    # the held ones carry the prior's 1-sigma, and every scale and bias is within 3 of it
    sd = np.sqrt(np.diag(res.covariance))
    np.testing.assert_allclose(sd[held], res.held_uncertainty.sigma[held], rtol=1e-9)
    z = (res.theta - truth.to_vector(res.layout)) / sd
    core = _core(names)
    assert np.all(np.abs(z[core]) < 3.0), dict(zip(np.array(names)[core], np.round(z[core], 2)))
    assert not any("moved off the prior" in n for n in res.notes)


@pytest.mark.parametrize(("seed", "positions"), [(0, 12), (1, 12), (2, 12), (3, 12), (4, 200)])
def test_without_a_prior_a_vessel_gives_a_partial_result_never_an_absurd_one(seed, positions):
    truth = CoefficientSet.seed_truth()
    pos = simulate_positions(truth, "vessel", positions, LAT, seed=seed)
    res = calibrate(pos, CalibrationOptions(latitude_deg=LAT))
    assert "ellipsoid fit is not supported by these positions" in res.prior_source
    assert res.observability.verdict == "insufficient"
    assert any(n.startswith("partial calibration") for n in res.notes)
    names = res.layout.names
    held = ~res.observability.estimated
    np.testing.assert_array_equal(res.theta[held], res.theta_prior[held])
    for sensor, bias_bound in (("gyro", 1.0), ("accel", 0.01)):  # deg/h, g
        k = res.coefficients.values[f"{sensor}.scale"] / truth.values[f"{sensor}.scale"]
        assert np.all(np.abs(k - 1) < 0.01), (sensor, k)
        assert np.all(np.abs(res.coefficients.values[f"{sensor}.bias"]) < bias_bound)
    sd = np.sqrt(np.diag(res.covariance))
    z = (res.theta - truth.to_vector(res.layout)) / sd
    core = _core(names)
    assert np.all(np.abs(z[core]) < 3.0), dict(zip(np.array(names)[core], np.round(z[core], 2)))
    # the reported 1-sigma is believable: not below what the window noise allows
    assert np.all(sd[core] > 1e-7 * np.abs(res.theta[core]))


def test_the_ellipsoid_start_is_used_only_where_the_noise_pins_it():
    truth = CoefficientSet.seed_truth()
    layout = ParameterLayout((Model.seed("gyro"), Model.seed("accel")))
    rich = data_prior(simulate_positions(truth, "24", None, LAT, seed=1), layout, LAT, 0.0, 50.0)
    assert set(rich.how.values()) == {"scale and bias from an ellipsoid fit"}
    scale = layout.term_slices()["accel.scale"]
    assert np.all(rich.sigma[scale] < 1e-3)  # its own 1-sigma: within the class default
    vessel = simulate_positions(truth, "vessel", 200, LAT, seed=2)
    flat = data_prior(vessel, layout, LAT, 0.0, 50.0)
    for sensor in ("gyro", "accel"):
        assert "not supported by these positions" in flat.how[sensor]
    np.testing.assert_array_equal(flat.theta, common_start(vessel, layout, LAT, 0.0))
    # the nominal start carries what a unit of unknown history may be off by
    sl = layout.term_slices()
    np.testing.assert_array_equal(flat.sigma[sl["gyro.bias"]], 0.5)  # deg/h
    np.testing.assert_array_equal(flat.sigma[sl["accel.bias"]], 1e-3)  # g
    assert np.all(flat.sigma[sl["gyro.scale"]] > 0.03 * flat.theta[sl["gyro.scale"]])
    assert np.all(np.isnan(flat.sigma[sl["gyro.misalignment"]]))


def test_an_unbelievable_result_names_the_coefficient():
    truth = CoefficientSet.seed_truth()
    pos = simulate_positions(truth, "24", None, LAT, seed=3)
    res = calibrate(pos, CalibrationOptions(latitude_deg=LAT))
    names = res.layout.names
    sd = np.sqrt(np.diag(res.covariance))
    sd_noise = np.sqrt(np.diag(res.covariance_measurement))
    est = res.observability.estimated
    typical = res.problem.layout.typical(res.theta_prior)

    def why(theta=res.theta, sd=sd, sd_noise=sd_noise):
        return unbelievable(res.problem, theta, res.theta_prior, typical, est, sd, sd_noise,
                            references(LAT, 0.0))  # fmt: skip

    assert why() is None
    bad = res.theta.copy()
    bad[names.index("accel.scale.Kz")] = 1e-5  # the scale factor
    assert "accel.scale.Kz" in why(theta=bad)
    bad = res.theta.copy()
    bad[names.index("accel.bias.bz")] = 141262.0  # and its vertical bias, in g
    assert "accel.bias.bz" in why(theta=bad)
    wide = sd.copy()
    wide[names.index("gyro.bias.by")] = 100.0  # deg/h: more than Earth rate itself
    assert "gyro.bias.by" in why(sd=wide)
    tiny = sd_noise.copy()
    tiny[names.index("gyro.scale.Ky")] *= 1e-3  # a 1-sigma the window noise cannot give
    assert "gyro.scale.Ky" in why(sd_noise=tiny) and "1-sigma" in why(sd_noise=tiny)


def test_an_unsupported_start_that_ran_away_is_exit_2_and_nothing_is_written(
    tmp_path, capsys, monkeypatch
):
    """The guard behind the start's refusal: accept any ellipsoid (as before) and the vessel's
    fit is refused with a reason naming the coefficient; -o writes nothing."""
    path = tmp_path / "v.csv"
    assert main(["simulate", "--design", "vessel", "--positions", "12", "--seed", "0",
                 "-o", str(path)]) == 0  # fmt: skip
    monkeypatch.setattr(start, "SUPPORT", np.inf)
    out = tmp_path / "c.json"
    capsys.readouterr()
    rc = main(["calibrate", str(path), "--latitude", "45", "--json", "-o", str(out)])
    err = capsys.readouterr()
    assert rc == 2 and err.out == "" and not out.exists()
    lines = err.err.strip().splitlines()
    assert "no believable calibration" in lines[-1] and ".scale.K" in lines[-1]
    assert "Traceback" not in err.err
    pos = simulate_positions(CoefficientSet.seed_truth(), "vessel", 12, LAT, seed=2)
    with pytest.raises(RecalInputError, match=r"no believable calibration.*\.scale\.K"):
        calibrate(pos, CalibrationOptions(latitude_deg=LAT))


def test_the_cli_without_a_prior_writes_a_partial_result(tmp_path, capsys):
    path = tmp_path / "v.csv"
    assert main(["simulate", "--design", "vessel", "--positions", "12", "--seed", "0",
                 "-o", str(path)]) == 0  # fmt: skip
    out = tmp_path / "c.json"
    capsys.readouterr()
    assert main(["calibrate", str(path), "--latitude", "45", "--json", "-o", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "held" in doc["status"]["accel"]["scale"] and out.exists()
    assert all(abs(k - 1) < 0.01 for k in doc["coefficients"]["accel"]["scale"])


def test_many_short_windows_with_slews_report_their_steps():
    """A voyage's thousands of windows: the slews are integrated once per distinct gyro, the LM
    re-linearises them only at its answers, and each step is reported."""
    truth = CoefficientSet.seed_truth()
    s = simulate_session(truth, "vessel", 300, LAT, seed=4, rate_hz=50.0, window_s=4.0,
                         slew_s=1.0, noise=NoiseSpec(arw_deg_rt_h=0.012))  # fmt: skip
    steps: list[int] = []
    res = calibrate(session_positions(s), CalibrationOptions(latitude_deg=LAT,
                    slews=session_slews(s)), progress=steps.append)  # fmt: skip
    assert len(steps) == len(LM_STEPS) and "slew" in res.problem.invariant_names
    assert res.convergence["converged"], res.convergence
    held = ~res.observability.estimated
    np.testing.assert_array_equal(res.theta[held], res.theta_prior[held])


def test_slews_are_integrated_once_per_distinct_gyro_with_the_same_residuals():
    truth = CoefficientSet.seed_truth()
    s = simulate_session(truth, "random", 6, LAT, seed=5, rate_hz=50.0, window_s=4.0, slew_s=2.0)
    pos, slews = session_positions(s), session_slews(s)
    res = calibrate(pos, CalibrationOptions(latitude_deg=LAT, slews=slews))
    problem, theta = res.problem, res.theta
    typical = problem.layout.typical(theta)
    # a Jacobian's points: half of them move the accelerometer only
    pts = np.concatenate([theta + 1e-3 * np.diag(typical), theta - 1e-3 * np.diag(typical)])
    same = problem._same_gyro(pts)
    assert same is not None and np.unique(same).size < pts.shape[0]
    one_by_one = np.concatenate([problem.raw_residuals(p[None])["slew"] for p in pts])
    np.testing.assert_array_equal(problem.raw_residuals(pts)["slew"], one_by_one)
