"""Model discrepancy: a hidden effect is found, named and removed; no effect, no alarm."""

import json

import numpy as np
import pytest

from recal.diagnose.effects import diagnose
from recal.model.coefficients import CoefficientSet
from recal.model.terms import catalogue_terms
from recal.report.html import diagnosis_html
from recal.sim.simulate import TemperatureSpec, simulate_positions
from recal.solve.options import CalibrationOptions
from service.cli.diagnose import format_diagnosis
from service.cli.main import main

CAT = catalogue_terms()
SWING = TemperatureSpec(start_c=15.0, slope_c_per_h=4.0, swing_c=8.0, period_h=0.7)


def _positions(hidden: list[str], seed: int, sensors=("gyro", "accel"), values=None):
    truth = CoefficientSet.seed_truth()
    for name, v in (values or {}).items():
        truth.values[name] = np.asarray(v, float)
    return simulate_positions(truth, "random", 36, 40.0, seed=seed, sensors=sensors,
                              temperature=SWING, hidden=[CAT[h] for h in hidden])  # fmt: skip


@pytest.mark.parametrize(
    ("effect", "values", "sensors"),
    [
        ("gyro.bias_temperature", [0.004, -0.003, 0.002], ("gyro",)),
        ("accel.scale_asymmetry", [2e-4, -1.5e-4, 1e-4], ("accel",)),
        ("gyro.bias_drift", [0.03, 0.0, -0.02], ("gyro", "accel")),
    ],
)
def test_hidden_effect_is_ranked_first_and_removes_the_excess(effect, values, sensors):
    pos = _positions([effect], seed=7, sensors=sensors, values={effect: values})
    d = diagnose(pos, CalibrationOptions(latitude_deg=40.0))
    top = d.candidates[0]
    assert top.effect == effect, [(c.effect, c.delta_bic) for c in d.candidates[:3]]
    assert top.significant and top.delta_bic < -10 and top.explained_fraction > 0.8
    assert d.suggested_effects[0] == effect
    assert d.chi2_red > 3 and d.final_chi2_red < 2
    # the estimated effect matches the hidden truth within its own uncertainty
    est = np.array(list(top.parameters.values()))
    sd = np.array(list(top.uncertainty.values()))
    assert np.all(np.abs(est - np.asarray(values)) < 4 * sd)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_no_hidden_effect_no_significant_candidate(seed):
    d = diagnose(_positions([], seed), CalibrationOptions(latitude_deg=40.0))
    assert not [c.effect for c in d.candidates if c.significant]
    assert d.suggested_effects == []
    for inv in d.invariants:
        assert inv["ratio"] < 1.5


def test_ramp_only_temperature_cannot_tell_temperature_from_drift():
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.bias_temperature"] = np.array([0.004, -0.003, 0.002])
    pos = simulate_positions(truth, "random", 36, 40.0, seed=5, sensors=("gyro",),
                             temperature=TemperatureSpec(10.0, 30.0),
                             hidden=[CAT["gyro.bias_temperature"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=40.0))
    top = {c.effect: c for c in d.candidates[:2]}
    assert set(top) == {"gyro.bias_temperature", "gyro.bias_drift"}
    assert "gyro.bias_drift" in top["gyro.bias_temperature"].similar_to
    # not a hard delta-BIC cut: the signatures' correlation, an evidence ratio and the advice
    (o,) = [o for o in top["gyro.bias_temperature"].confounded_with
            if o["effect"] == "gyro.bias_drift"]  # fmt: skip
    assert o["signature_correlation"] > 0.95 and o["evidence_ratio"] > 0
    assert "temperature swing" in o["advice"]
    assert "temperature swing" in format_diagnosis(d) and "temperature swing" in diagnosis_html(d)


def test_constant_temperature_effect_is_not_identifiable():
    pos = _positions([], seed=1, sensors=("gyro",))
    pos.columns["temperature_c"] = np.full(len(pos), 25.0)
    d = diagnose(pos, CalibrationOptions(latitude_deg=40.0),
                 candidates=["gyro.bias_temperature"])  # fmt: skip
    (c,) = d.candidates
    assert not c.identifiable and "cannot show it" in c.reason


def test_cli_json_contract_and_html_report(tmp_path, capsys):
    pos = _positions(["gyro.bias_temperature"], seed=3, sensors=("gyro",),
                     values={"gyro.bias_temperature": [0.004, -0.003, 0.002]})  # fmt: skip
    csv = tmp_path / "pos.csv"
    csv.write_text(pos.to_csv_text())
    report = tmp_path / "report.html"
    rc = main(["diagnose", str(csv), "--latitude", "40", "--json", "--report", str(report)])
    out = capsys.readouterr().out
    assert rc == 0
    doc = json.loads(out)
    inv = doc["invariants"][0]
    assert {"name", "rms", "noise_floor"} <= set(inv) and inv["name"] == "gyro_norm"
    c = doc["candidates"][0]
    assert {"effect", "delta_bic", "p_value", "significant", "explained_fraction"} <= set(c)
    assert c["effect"] == "gyro.bias_temperature" and c["significant"]
    page = report.read_text()
    assert page.startswith("<!doctype html>") and "<svg" in page and "gyro.bias_temperature" in page
    # the text report names the fix
    assert main(["diagnose", str(csv), "--latitude", "40"]) == 0
    assert "--effects +gyro.bias_temperature" in capsys.readouterr().out


def test_html_report_is_self_contained():
    d = diagnose(_positions([], seed=4, sensors=("accel",)), CalibrationOptions(latitude_deg=40.0))
    page = diagnosis_html(d)
    assert "No candidate effect is significant" in page
    names = ("http://www.w3.org/2000/svg", "http://www.w3.org/1999/xlink")  # SVG namespaces
    assert "http" not in page.replace(names[0], "").replace(names[1], "")  # no external assets


def test_a_candidate_taking_a_share_of_another_effects_misfit_is_judged_against_the_excess():
    """A real temperature effect: other candidates take a share of its misfit, but the baseline's
    misfit is just as well an independent excess on each window (recal.diagnose.hypotheses),
    so a share is no evidence: their delta BIC is measured from that best null and stays
    positive, and only the effect that explains the residual is significant."""
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.bias_temperature"] = np.array([0.0015, -0.0015, 0.0015])
    swing = TemperatureSpec(start_c=15.0, slope_c_per_h=4.0, swing_c=8.0, period_h=0.7)
    pos = simulate_positions(truth, "random", 24, 40.0, seed=0, temperature=swing,
                             hidden=[CAT["gyro.bias_temperature"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=40.0))
    top = d.candidates[0]
    assert top.effect == "gyro.bias_temperature" and top.significant
    assert top.disagreement == ""
    assert top.hypotheses["null"] == "noise" and top.hypotheses["best"] == "effect"
    assert top.hypotheses["effect"] < top.hypotheses["noise"] < top.hypotheses["nothing"]
    rest = [c for c in d.candidates[1:] if c.identifiable]
    assert rest and not any(c.significant for c in rest)
    shares = [c for c in rest if c.explained_fraction > 0.3]
    assert shares, [(c.effect, c.explained_fraction) for c in rest]
    assert all(c.delta_bic > 0 for c in shares), [(c.effect, c.delta_bic) for c in shares]
    assert d.explanation == "effect" and "alone explains it worse" in d.verdict


def test_a_candidate_whose_delta_bic_and_p_value_disagree_is_explained():
    """delta BIC below 0 and a family-wise p above ALPHA: the note says why, and names the
    effect that explains the misfit better."""
    from recal.diagnose.candidates import Candidate

    c = Candidate("gyro.bias_drift", "", True, delta_bic=-12.0, p_adjusted=0.2,
                  explained_fraction=0.3, added_directions=3,
                  explained_better_by="gyro.bias_temperature")  # fmt: skip
    assert "another effect explains better (gyro.bias_temperature)" in c.disagreement
    assert c.to_json_dict()["disagreement"] == c.disagreement
    agree = Candidate("gyro.bias_temperature", "", True, delta_bic=-50.0, p_adjusted=1e-9)
    assert agree.disagreement == ""
