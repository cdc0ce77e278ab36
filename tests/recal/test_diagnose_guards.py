"""Guards against the right residual for the wrong reason: core-coefficient shifts and
trade-off warnings, confounding by signature correlation, the seeds' 24-position design never
refused, and a plain verdict when the model still fails."""

import json
from pathlib import Path

import numpy as np
import pytest

from recal.diagnose.effects import diagnose
from recal.model.coefficients import CoefficientSet
from recal.model.plugins import hidden_plugin
from recal.model.terms import catalogue_terms
from recal.report.html import diagnosis_html
from recal.sim.simulate import TemperatureSpec, design_orientations, simulate_positions
from recal.solve.options import CalibrationOptions
from service.cli.common import load_plugin
from service.cli.diagnose import format_diagnosis
from service.cli.main import main

CAT = catalogue_terms()
FARADAY = Path(__file__).resolve().parents[2] / "docs" / "examples" / "faraday_plugin.py"
SWING = TemperatureSpec(start_c=15.0, slope_c_per_h=4.0, swing_c=8.0, period_h=0.7)


def _magnetic(seed: int):
    """A FOG Faraday sensitivity in the data, no plugin given: out of the catalogue."""
    (term,) = load_plugin(str(FARADAY))
    C = design_orientations("random", 24, np.random.default_rng(seed))
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.faraday"] = np.array([0.04, -0.03, 0.05])
    return simulate_positions(truth, "random", 24, 45.0, seed=seed,
                              hidden=[hidden_plugin(term, C, 45.0)])  # fmt: skip


def test_g_sensitivity_absorbing_a_magnetic_effect_carries_its_warning(tmp_path, capsys):
    pos = _magnetic(seed=1)
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0))
    (top,) = [c for c in d.candidates if c.effect == d.suggested_effects[0]]
    assert top.effect == "gyro.g_sensitivity"
    assert top.trade_off["coefficient"].startswith("gyro.scale.")
    assert abs(top.trade_off["shift_sigma"]) >= 5 and top.trade_off["correlation"] >= 0.9
    assert "trade off" in top.warning and "second site latitude" in top.advice
    assert "wrong reason" in d.verdict
    assert f"warning: adding gyro.g_sensitivity moves {top.trade_off['coefficient']}" in (
        format_diagnosis(d)
    )
    assert "trade off in these positions" in diagnosis_html(d)
    csv = tmp_path / "mag.csv"
    csv.write_text(pos.to_csv_text())
    assert main(["diagnose", str(csv), "--latitude", "45", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    c = doc["candidates"][0]
    assert c["effect"] == "gyro.g_sensitivity" and "trade off" in c["warning"]
    assert set(c["trade_off"]) == {"coefficient", "shift_sigma", "correlation"}


def test_a_true_effect_that_does_not_trade_off_carries_no_warning():
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.bias_drift"] = np.array([0.03, 0.0, -0.02])
    pos = simulate_positions(truth, "random", 36, 40.0, seed=7, temperature=SWING,
                             hidden=[CAT["gyro.bias_drift"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=40.0))
    top = d.candidates[0]
    assert top.effect == "gyro.bias_drift" and top.warning == ""
    assert top.core_shift and "wrong reason" not in d.verdict


VALUES = {  # a few times the typical change, so each effect is well above the noise
    "gyro.bias_temperature": [0.02, -0.015, 0.01],
    "gyro.scale_temperature": [1e-4, -8e-5, 6e-5],
    "gyro.bias_temperature_rate": [0.05, -0.04, 0.03],
    "gyro.g_sensitivity": [0.1, -0.05, 0.03, 0.02, 0.08, -0.04, 0.05, 0.03, -0.1],
    "gyro.bias_drift": [0.03, 0.0, -0.02],
    "accel.bias_temperature": [1e-4, -8e-5, 6e-5],
    "accel.scale_temperature": [1e-4, -8e-5, 6e-5],
    "accel.scale_asymmetry": [2e-4, -1.5e-4, 1e-4],
}


#: Each catalogue effect with both triads, and the gyro effects a gyro-only session can carry
#: (g-sensitivity needs the accelerometers to know where gravity points).
NEVER_REFUSED = [(e, False) for e in sorted(CAT)] + [
    (e, True) for e in sorted(CAT) if CAT[e].sensor == "gyro" and e != "gyro.g_sensitivity"
]


@pytest.mark.parametrize(("effect", "gyro_only"), NEVER_REFUSED)
def test_24_position_design_with_each_catalogue_effect_is_never_refused(effect, gyro_only):
    sensors = ("gyro",) if gyro_only else ("gyro", "accel")
    truth = CoefficientSet.seed_truth()
    truth.values[effect] = np.array(VALUES[effect])
    pos = simulate_positions(truth, "24", None, 45.0, seed=0, temperature=SWING,
                             sensors=sensors, hidden=[CAT[effect]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0))  # raises nothing
    assert d.verdict and np.isfinite(d.final_chi2_red)
    assert d.model_fails == ("still fails" in d.verdict)
    if gyro_only or effect == "accel.scale_asymmetry":
        # gyro alone: the norm sees a bias change only along Earth rate; asymmetry: |f| is
        # nearly the f**2 pattern of accel.quadratic on this design
        assert effect not in d.suggested_effects or d.final_chi2_red < d.chi2_red
    else:  # with both triads and a temperature swing the design shows every other effect
        assert d.suggested_effects[:1] == [effect], [(c.effect, c.delta_bic) for c in d.candidates]
        assert d.final_chi2_red < min(2.0, d.chi2_red)


def test_shupe_effect_on_the_gyro_only_24_position_design_is_found():
    """A large Shupe effect drags the gyro-only baseline into its degenerate valley (scale
    factors running to infinity); diagnose still finds the effect instead of refusing."""
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.bias_temperature_rate"] = np.array(VALUES["gyro.bias_temperature_rate"])
    pos = simulate_positions(truth, "24", None, 45.0, seed=1, temperature=SWING,
                             sensors=("gyro",), hidden=[CAT["gyro.bias_temperature_rate"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0))
    assert d.suggested_effects[:1] == ["gyro.bias_temperature_rate"]
    assert d.final_chi2_red < 2 and not d.model_fails
    assert any("degenerate" in n for n in d.notes)


def test_model_that_still_fails_says_so():
    d = diagnose(_magnetic(seed=2), CalibrationOptions(latitude_deg=45.0),
                 candidates=["gyro.bias_drift", "accel.scale_asymmetry"])  # fmt: skip
    assert d.model_fails and d.final_chi2_red > 2
    assert "the model still fails" in d.verdict and "--plugin" in d.verdict
    assert "chi2_red" in d.verdict and "worst positions" in d.verdict
    assert d.residual_correlations
    assert "the model still fails" in format_diagnosis(d)
    assert "the model still fails" in diagnosis_html(d)


def test_model_ladder_in_json_text_and_html():
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.bias_temperature"] = np.array([0.004, -0.003, 0.002])
    pos = simulate_positions(truth, "random", 36, 40.0, seed=3, sensors=("gyro",),
                             temperature=SWING, hidden=[CAT["gyro.bias_temperature"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=40.0))
    doc = d.to_json_dict()
    base, step = doc["ladder"][:2]
    assert base["model"] == "baseline" and base["delta_bic"] is None
    assert step["effect"] == "gyro.bias_temperature" and step["delta_bic"] < -10
    assert step["rms_over_floor"]["gyro_norm"] < base["rms_over_floor"]["gyro_norm"]
    assert "model ladder:" in format_diagnosis(d)
    page = diagnosis_html(d)
    assert "Model ladder" in page and "Fitted effect parameters" in page and "kTx" in page


def test_noise_correlation_matches_simulated_window_noise():
    """The gyro norm and the dot product of one window share its gyro noise: the predicted
    correlation of their whitened residuals matches simulated noise (fixed 24-position
    orientations, 150 noise draws, evaluated at the truth)."""
    from recal.diagnose.effects import noise_correlation
    from recal.model.error_model import ParameterLayout
    from recal.solve.problem import Problem

    truth = CoefficientSet.seed_truth()
    runs = []
    for seed in range(150):
        pos = simulate_positions(truth, "24", None, 70.0, seed=seed)
        if seed == 0:
            base = diagnose(pos, CalibrationOptions(latitude_deg=70.0), candidates=[]).baseline
            models = base.problem.models
            theta = truth.to_vector(ParameterLayout(models))
        prob = Problem.build(pos, models, 70.0, 0.0, theta)
        runs.append(prob.residuals(theta[None])[0])
    E = np.array(runs)
    M = prob.M
    predicted = noise_correlation(prob, theta)
    i, j = np.arange(M), 2 * M + np.arange(M)  # gyro_norm and dot of the same window
    empirical = np.array([np.corrcoef(E[:, a], E[:, b])[0, 1] for a, b in zip(i, j)])
    assert np.mean(predicted[i, j]) > 0.8  # Earth rate nearly along gravity at 70 deg
    assert abs(np.mean(empirical) - np.mean(predicted[i, j])) < 0.05


@pytest.mark.parametrize("seed", [31, 197])
def test_clean_high_latitude_sessions_raise_no_alarm(seed):
    """Sessions where Bonferroni on the nominal F-test (independent residuals) raised a false
    gyro.bias_temperature alarm; the calibrated family-wise p-value does not."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(12, 37))
    lat = float(rng.choice([0.0, 20.0, 45.0, 60.0, 70.0]))
    pos = simulate_positions(CoefficientSet.seed_truth(), "random", n, lat, seed=seed,
                             temperature=SWING if seed % 2 else TemperatureSpec(20.0, 2.0))  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=lat))
    assert not [c.effect for c in d.candidates if c.significant]
    top = d.candidates[0]
    assert top.p_value < 0.01 / 8 < top.p_adjusted  # nominal would have alarmed


def test_an_effect_the_design_confounds_names_what_it_cannot_be_separated_from():
    """On a steady ramp the temperature rate is constant: a Shupe bias is a constant bias."""
    truth = CoefficientSet.seed_truth()
    pos = simulate_positions(truth, "24", None, 45.0, seed=0, sensors=("gyro",),
                             temperature=TemperatureSpec(20.0, 2.0))  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0),
                 candidates=["gyro.bias_temperature_rate"])  # fmt: skip
    (c,) = d.candidates
    assert not c.identifiable and "cannot be separated from gyro.bias." in c.reason


def test_effect_far_above_its_typical_size_is_fitted_not_dismissed():
    """A gyro scale-factor temperature coefficient ten times its typical change: the data pin
    it down worse than the typical size along some directions, yet it explains the excess."""
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.scale_temperature"] = np.array(VALUES["gyro.scale_temperature"])
    pos = simulate_positions(truth, "random", 24, 45.0, seed=1000, temperature=SWING,
                             hidden=[CAT["gyro.scale_temperature"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0))
    assert d.candidates[0].effect == "gyro.scale_temperature" and d.candidates[0].significant
    assert not d.model_fails and d.final_chi2_red < 1.5 < d.chi2_red
