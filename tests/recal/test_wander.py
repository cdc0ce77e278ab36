"""Bias wander between windows (issue 26): windows 1.5 h apart whose biases follow a
Gauss-Markov process (tau 4 h) at 1-2 times the window noise for the gyro and 1-6 times for
the accelerometer. Treated as independent, the fit's chi2_red is 4-7 and its sigmas do not
cover the truth; with the wander estimated from the residuals (``wander="auto"``) and carried
in the windows' covariance, chi2_red is about 1 and they do."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import NoiseSpec, simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from recal.solve.wander_covariance import correlation, whitener
from recal.solve.wander_model import TriadWander, WanderModel

TRUTH = CoefficientSet.seed_truth()


def _session(
    seed: int,
    wander: bool = True,
    windows: int = 30,
    gap_s: float = 4800.0,
    window_s: float = 600,
    truth: CoefficientSet = TRUTH,
):
    rng = np.random.default_rng(1000 + seed)
    base = NoiseSpec(window_s=window_s, slew_s=gap_s, rate_hz=100.0)
    g_sem = base.per_sample_sigma("gyro") / np.sqrt(window_s * 100)
    a_sem = base.per_sample_sigma("accel") / np.sqrt(window_s * 100)
    k = 1.0 if wander else 0.0
    noise = NoiseSpec(
        window_s=window_s, slew_s=gap_s, rate_hz=100.0, gm_tau_s=4 * 3600.0,
        gm_gyro_dph=k * g_sem * rng.uniform(1, 2), gm_accel_ug=k * a_sem * 1e6 * rng.uniform(1, 6),
    )  # fmt: skip
    return simulate_positions(truth, "random", windows, 45.0, seed=seed, noise=noise)


def _z(res) -> np.ndarray:
    names = res.layout.names
    core = np.array([".scale." in n or ".bias." in n for n in names]) & res.observability.estimated
    sd = np.sqrt(np.diag(res.covariance))
    return ((res.theta - TRUTH.to_vector(res.layout)) / sd)[core]


def test_wander_between_windows_keeps_the_sigmas_honest() -> None:
    """Seeds not tuned on (the estimator was tuned on 100-109): all 12 scale and bias of each
    session, 8 sessions."""
    z_none, z_auto, chi_none, chi_auto = [], [], [], []
    for seed in range(200, 208):
        pos = _session(seed)
        plain = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm"))
        auto = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm", wander="auto"))
        z_none.extend(_z(plain))
        z_auto.extend(_z(auto))
        chi_none.append(plain.chi2_red)
        chi_auto.append(auto.chi2_red)
        doc = auto.to_json_dict()
        assert doc["noise_model"]["wander"]["kind"] == "gauss-markov"  # the JSON names it
        for t in auto.noise_model["wander_test"]:  # carried at the 84 %, drift at the 95 % bound
            if t["sigma"] > 0:
                assert t["sigma"] < t["sigma_carried"] < t["sigma_upper"] < 3 * t["sigma"]
        assert any("share a bias wander" in n for n in auto.notes)
    z_none, z_auto = np.abs(z_none), np.abs(z_auto)
    assert np.median(chi_none) > 2.5  # the misfit wander leaves when ignored
    assert 0.7 < np.median(chi_auto) < 1.3
    assert np.sqrt(np.mean(z_auto**2)) < 1.3
    assert np.mean(z_auto < 3.0) >= 0.98
    assert np.mean(z_none < 3.0) < np.mean(z_auto < 3.0)


def test_no_wander_is_claimed_most_of_the_time() -> None:
    """Without wander the test keeps none in 5 of 6 sessions. A triad whose likelihood still rose
    is carried at its estimate, unclaimed (its JSON says significant false, the note says none
    is shown): the estimate moves by less than its sigma, and nothing changes where none rose."""
    claimed = 0
    for seed in range(300, 306):
        pos = _session(seed, wander=False)
        plain = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm"))
        auto = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm", wander="auto"))
        tests = auto.noise_model["wander_test"]
        block = auto.noise_model["wander"]
        if any(t["significant"] for t in tests):
            claimed += 1
            continue
        if block is None:
            assert all(t["gain_2lnL"] <= 0 or t["sigma"] == 0 for t in tests)
            np.testing.assert_array_equal(auto.theta, plain.theta)
            continue
        carried = [s for s in ("gyro", "accel") if s in block]
        assert carried and all(block[s]["significant"] is False for s in carried)
        assert not any("share a bias wander" in n for n in auto.notes)
        assert any("cannot rule one out" in n for n in auto.notes)
        shift = np.abs(auto.theta - plain.theta) / np.sqrt(np.diag(plain.covariance))
        assert shift.max() < 1.0
        assert WanderModel.from_json_dict(block).unproven == frozenset(carried)
    assert claimed <= 1


def test_a_short_session_is_not_searched_for_wander() -> None:
    """Over minutes an excess misfit is model error, which wander would only hide."""
    pos = _session(1, windows=12, gap_s=30.0, window_s=100.0)
    res = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm", wander="auto"))
    assert res.noise_model["wander"] is None
    assert res.noise_model["wander_test"].startswith("not estimated: the windows span")


def test_a_given_wander_model_round_trips_and_is_used(tmp_path) -> None:
    Kg = np.abs(TRUTH.values["gyro.scale"])
    model = WanderModel({"gyro": TriadWander(0.003 * Kg, np.full(3, 14400.0))}, "given")
    back = WanderModel.from_json_dict(json.loads(json.dumps(model.to_json_dict())))
    np.testing.assert_allclose(back.triads["gyro"].sigma, model.triads["gyro"].sigma)
    pos = _session(3)
    res = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm", wander=back))
    assert res.noise_model["wander"]["gyro"]["tau_s"] == [14400.0] * 3
    assert res.problem.wander_cov is not None
    plain = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm"))
    gyro_bias = [k for k, n in enumerate(res.layout.names) if n.startswith("gyro.bias")]
    sd = np.sqrt(np.diag(res.covariance))[gyro_bias]
    sd0 = np.sqrt(np.diag(plain.covariance_measurement))[gyro_bias]
    assert np.all(sd > sd0)  # the shared wander widens what the windows know of the bias


def test_the_whitener_whitens() -> None:
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 86400.0, 20))
    g = rng.normal(size=(20, 20))
    cov = g @ (2.0 * correlation(t, 7200.0)) @ g.T
    sigma = rng.uniform(0.5, 2.0, 20)
    W = whitener(sigma, cov)
    C = np.eye(20) + cov / np.outer(sigma, sigma)
    np.testing.assert_allclose(W @ C @ W.T, np.eye(20), atol=1e-9)
    assert np.allclose(correlation(t, 0.0), np.eye(20))
    assert np.allclose(correlation(t, np.inf), 1.0)


def test_a_bad_wander_model_is_refused() -> None:
    from recal.errors import RecalInputError

    with pytest.raises(RecalInputError, match="sigma"):
        WanderModel.from_json_dict({"gyro": {"tau_s": [1, 2, 3]}})
    with pytest.raises(RecalInputError, match=">= 0"):
        TriadWander(np.array([-1.0, 0, 0]), np.zeros(3))


def test_the_drift_test_does_not_read_wander_as_a_step() -> None:
    """60 windows 1.5 h apart with wander: calibrated on the first 30 (wander estimated), the
    drift test on the next 30 of the unchanged unit. Taken as independent, wander accumulates
    into a false step (8 alarms in 8 sessions, measured); as innovations under the accepted
    wander model it mostly does not, and a real step (+3000 ppm on the gyro z scale half way)
    is still found."""
    from recal.diagnose.drift import DriftConfig, drift_inputs, drift_test
    from recal.model.positions import Positions

    false = {"plain": 0, "wander": 0}
    found = 0
    for seed in range(520, 524):
        pos = _session(seed, windows=60)
        cal = calibrate(
            pos.subset(np.arange(30)),
            CalibrationOptions(latitude_deg=45.0, method="lm", wander="auto"),
        )
        wander = cal.noise_model["wander"]
        assert wander is not None
        later = pos.subset(np.arange(30, 60))
        cfg = DriftConfig.per_days(30, 16)
        for name, w in (("plain", None), ("wander", wander)):
            inputs = drift_inputs(later, cal.coefficients, cal.covariance, 45.0, 0.0, wander=w)
            false[name] += drift_test(inputs, cfg).alarm_window is not None
        vals = {k: v.copy() for k, v in TRUTH.values.items()}
        vals["gyro.scale"] = vals["gyro.scale"] * np.array([1.0, 1.0, 1.003])
        changed = _session(seed, windows=60, truth=CoefficientSet(vals))
        cols = {
            k: np.concatenate([pos.columns[k][30:45], changed.columns[k][45:60]])
            for k in pos.columns
        }
        inputs = drift_inputs(
            Positions.from_columns(cols), cal.coefficients, cal.covariance, 45.0, 0.0, wander=wander
        )
        found += drift_test(inputs, cfg).alarm_window is not None
    assert false["plain"] >= 3
    assert false["wander"] <= 1
    assert found == 4


def test_two_triads_each_short_of_the_threshold_are_kept_together() -> None:
    """Each triad tested alone falls just short (gains 11.3 and 8.7 against 11.34) although the
    windows' misfit is plain (chi2_red 1.73 on 90 residuals): the joint test keeps both (issue
    26's benchmark, unit 2613: wander at 0.66 and 1.48 times the window noise, tau 2.3 h, windows
    4.75 h apart)."""
    window_s, gap_s = 600.0, 4.7507 * 3600.0
    base = NoiseSpec(window_s=window_s, rate_hz=100.0)
    n = window_s * 100.0
    noise = NoiseSpec(
        window_s=window_s, slew_s=gap_s - window_s, rate_hz=100.0, gm_tau_s=2.2665 * 3600.0,
        gm_gyro_dph=0.6582 * base.per_sample_sigma("gyro") / np.sqrt(n),
        gm_accel_ug=1.4833 * base.per_sample_sigma("accel") / np.sqrt(n) * 1e6,
    )  # fmt: skip
    lat = 38.843
    pos = simulate_positions(TRUTH, "random", 60, lat, seed=2613, noise=noise).subset(np.arange(30))
    plain = calibrate(pos, CalibrationOptions(latitude_deg=lat, method="lm"))
    auto = calibrate(pos, CalibrationOptions(latitude_deg=lat, method="lm", wander="auto"))
    tests = auto.noise_model["wander_test"]
    assert all(t["gain_2lnL"] < t["threshold"] for t in tests)  # neither alone
    assert all(t["significant"] and t["joint_gain_2lnL"] > 16.81 for t in tests)
    assert set(auto.noise_model["wander"]) >= {"gyro", "accel"}
    assert plain.chi2_red > 1.5 and 0.7 < auto.chi2_red < 1.3


def test_the_drift_test_allows_for_the_wander_no_test_kept() -> None:
    """possible_wander: every triad tested, kept or not, at the upper bound of its sigma."""
    from recal.solve.wander_model import possible_wander

    assert possible_wander(None) is None
    assert possible_wander({"wander": None, "wander_test": "not estimated: ..."}) is None
    kept = {"kind": "gauss-markov", "gyro": {"sigma": [1.0] * 3, "tau_s": [3600.0] * 3}}
    tests = [
        {"sensor": "gyro", "significant": True, "sigma": 1.0, "sigma_upper": 1.4, "tau_s": 3600.0},
        {"sensor": "accel", "significant": False, "sigma": 2e-6, "sigma_upper": 3e-6,
         "tau_s": 7200.0},
    ]  # fmt: skip
    model = possible_wander({"wander": kept, "wander_test": tests})
    assert set(model.triads) == {"gyro", "accel"}
    np.testing.assert_array_equal(model.triads["gyro"].sigma, [1.4] * 3)
    np.testing.assert_array_equal(model.triads["accel"].sigma, [3e-6] * 3)
    np.testing.assert_array_equal(model.triads["accel"].tau_s, [7200.0] * 3)
    tests[1]["sigma"] = tests[1]["sigma_upper"] = 0.0  # nothing to allow for
    assert set(possible_wander({"wander": kept, "wander_test": tests}).triads) == {"gyro"}
    given = possible_wander({"wander": kept})  # a given model (no test): as given
    np.testing.assert_array_equal(given.triads["gyro"].sigma, [1.0] * 3)


def test_recal_drift_reads_the_wander_of_a_calibrate_document(tmp_path, capsys) -> None:
    """``recal drift --coefficients`` on calibrate's --json output takes its noise_model's
    wander (the note says so); ``--wander none`` takes the windows as independent."""
    from service.cli.main import main

    pos = _session(521, windows=60)
    (tmp_path / "fit.csv").write_text(pos.subset(np.arange(30)).to_csv_text())
    (tmp_path / "new.csv").write_text(pos.subset(np.arange(30, 60)).to_csv_text())
    assert main(["calibrate", str(tmp_path / "fit.csv"), "--latitude", "45", "--method", "lm",
                 "--json"]) == 0  # fmt: skip
    doc = capsys.readouterr().out
    assert json.loads(doc)["noise_model"]["wander"] is not None
    (tmp_path / "fit.json").write_text(doc)
    notes = {}
    for wander in ("auto", "none"):
        assert main(["drift", str(tmp_path / "new.csv"), "--coefficients", str(tmp_path / "fit.json"),
                     "--latitude", "45", "--json", "--wander", wander]) == 0  # fmt: skip
        notes[wander] = " ".join(json.loads(capsys.readouterr().out)["notes"])
    assert "innovations under the accepted version's bias wander" in notes["auto"]
    assert "bias wander" not in notes["none"]


def test_the_wander_modules_hold_one_idea_each_and_the_documented_names_stay() -> None:
    """Issue 38: recal.solve.wander is split by idea (types, chain, covariance, likelihood,
    estimate), each under 600 lines; the names docs/noise.md gives under recal.solve.wander
    still import from there, as the same objects."""
    import importlib
    from pathlib import Path

    import recal.solve.wander as wander
    from recal.solve.wander_covariance import innovations
    from recal.solve.wander_estimate import correlation_times, tau_floor_s

    assert (wander.innovations, wander.correlation_times, wander.tau_floor_s) == (
        innovations, correlation_times, tau_floor_s)  # fmt: skip
    for part in ("model", "chain", "covariance", "likelihood", "estimate"):
        module = importlib.import_module(f"recal.solve.wander_{part}")
        assert len(Path(module.__file__).read_text().splitlines()) < 600, part
