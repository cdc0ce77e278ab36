"""An effect that fits for the wrong reason is not reported as a success (issue 18 item 10).

The reproduction: a FOG with a magnetic (Faraday) bias, a heading-dependent effect outside the
catalogue (the plugin in docs/examples is the hidden truth, not given to diagnose). At one site
``gyro.g_sensitivity`` absorbs it: chi2_red falls to the floor while the gyro scale factors move
several sigma away from the truth. Seed 6 is a case whose trade-off correlation stays below the
older warning's 0.9, so only the core-shift rule speaks."""

import json
from pathlib import Path

import numpy as np
import pytest

from recal.diagnose.effects import (
    CORE_SHIFT_SIGMA,
    diagnose,
    effects_check,
    fit_effects,
    heldout_chi2_red,
)
from recal.model.coefficients import CoefficientSet
from recal.model.plugins import hidden_plugin
from recal.model.terms import catalogue_terms
from recal.report.html import diagnosis_html
from recal.sim.simulate import TemperatureSpec, design_orientations, simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.cli.diagnose import format_diagnosis
from service.cli.main import main
from service.gate import GateConfig, gate

FARADAY = Path(__file__).resolve().parents[2] / "docs" / "examples" / "faraday_plugin.py"
G_SENS = "gyro.g_sensitivity"
LAT = 45.0


def _magnetic(seed: int):
    from service.cli.common import load_plugin

    (term,) = load_plugin(str(FARADAY))
    C = design_orientations("random", 24, np.random.default_rng(seed))
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.faraday"] = np.array([0.04, -0.03, 0.05])  # deg/h per gauss
    pos = simulate_positions(truth, "random", 24, LAT, seed=seed,
                             hidden=[hidden_plugin(term, C, LAT)])  # fmt: skip
    return pos, truth


@pytest.fixture(scope="module")
def magnetic():
    pos, truth = _magnetic(seed=6)
    return pos, truth, diagnose(pos, CalibrationOptions(latitude_deg=LAT))


def test_the_absorbed_effect_really_moves_the_scale_factors_off_the_truth(magnetic):
    """What the rule guards against, measured: with g-sensitivity the fit is at the floor, its
    reported sigma shrinks, and the scale factors are further from the truth in those sigma."""
    pos, truth, _ = magnetic
    K0 = truth.values["gyro.scale"]
    z = {}
    for effects in ((), (G_SENS,)):
        r = calibrate(pos, CalibrationOptions(latitude_deg=LAT, effects=effects))
        K = r.theta[r.layout.term_slices()["gyro.scale"]]
        z[effects] = (K - K0) / r.uncertainty["gyro.scale"]
        if effects:
            assert r.chi2_red < 1.5
    assert np.max(np.abs(z[(G_SENS,)])) > 4 > np.max(np.abs(z[()]))


def test_a_large_core_shift_is_not_confirmed_in_the_candidate_verdict_and_json(magnetic):
    _, _, d = magnetic
    assert d.suggested_effects == [G_SENS] and d.final_chi2_red < 1.5 < d.chi2_red
    (top,) = [c for c in d.candidates if c.effect == G_SENS]
    shift = abs(top.trade_off["shift_sigma"])
    assert shift > CORE_SHIFT_SIGMA and top.trade_off["correlation"] < 0.9
    assert top.warning == ""  # the older trade-off warning stays silent here ...
    assert not top.trustworthy  # ... the core-shift rule does not
    for words in ("heading-dependent", "magnetic", "--plugin", "hold out positions",
                  "independent reference", f"{shift:.1f} sigma"):  # fmt: skip
        assert words in top.check, words
    # the diagnosis: the same shift from the baseline to the suggested model
    assert not d.trustworthy and abs(d.core_shift[top.trade_off["coefficient"]]) > 3
    assert "at the noise floor" in d.verdict and "NOT CONFIRMED" in d.verdict
    assert "heading-dependent" in d.verdict and "not better than the seed model" in d.verdict
    text = format_diagnosis(d)
    assert "NOT CONFIRMED: see the verdict" in text.split("suggested:")[1].splitlines()[0]
    doc = d.to_json_dict()
    assert doc["trustworthy"] is False and "NOT CONFIRMED" in doc["warning"]
    c = next(c for c in doc["candidates"] if c["effect"] == G_SENS)
    assert c["trustworthy"] is False and c["check"] == top.check
    # held-out beside in-sample: the baseline misfits positions it did not see as much as
    # those it saw; with the effect they are predicted to the floor (one site: the held-out
    # check cannot tell this effect from the true one, docs/diagnose.md)
    base, step = doc["ladder"]
    assert base["heldout_chi2_red"] > 3 and step["heldout_chi2_red"] < 1.5
    assert "(held out " in text and c["heldout_chi2_red"] == pytest.approx(
        step["heldout_chi2_red"], rel=1e-6
    )
    page = diagnosis_html(d)
    assert (
        "<b>Not confirmed</b>: see the verdict" in page and "held out (leave-one-position" in page
    )


def test_a_true_effect_that_barely_moves_the_core_stays_trusted():
    """A temperature swing separates a true accel scale-temperature effect from the seed
    coefficients: they move by less than 3 sigma and nothing is flagged."""
    truth = CoefficientSet.seed_truth()
    truth.values["accel.scale_temperature"] = np.array([1e-4, -8e-5, 6e-5])
    swing = TemperatureSpec(start_c=15.0, slope_c_per_h=4.0, swing_c=8.0, period_h=0.7)
    pos = simulate_positions(truth, "24", None, LAT, seed=0, temperature=swing,
                             hidden=[catalogue_terms()["accel.scale_temperature"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=LAT),
                 candidates=["accel.scale_temperature", "accel.bias_temperature"])  # fmt: skip
    assert d.suggested_effects[:1] == ["accel.scale_temperature"]
    assert d.trustworthy and d.warning == "" and "NOT CONFIRMED" not in d.verdict
    assert max(abs(v) for v in d.core_shift.values()) <= CORE_SHIFT_SIGMA


def test_heldout_chi2_is_one_for_a_right_model_and_exact_for_the_linearised_fit():
    vals = []
    for seed in range(6):
        pos = simulate_positions(CoefficientSet.seed_truth(), "random", 24, LAT, seed=seed)
        opt = CalibrationOptions(latitude_deg=LAT, refuse_at_solution=False)
        fit = fit_effects(calibrate(pos, opt), opt, [])
        vals.append(heldout_chi2_red(fit))
    assert 0.8 < np.mean(vals) < 1.25, vals
    # the closed form is leave-one-position-out: refit without the position, predict it
    M, r, J = fit.problem.M, fit.residual(), fit.jac
    rows = np.stack([np.arange(k * M, (k + 1) * M) for k in range(3)], axis=1)  # (M, 3)
    press = 0.0
    for i in range(M):
        keep = np.setdiff1d(np.arange(len(r)), rows[i])
        step, *_ = np.linalg.lstsq(J[keep], -r[keep], rcond=None)
        e = r[rows[i]] + J[rows[i]] @ step
        press += e @ e
    H = J @ np.linalg.pinv(J)
    expected = sum(np.trace(np.linalg.inv(np.eye(3) - H[np.ix_(g, g)])) for g in rows)
    assert heldout_chi2_red(fit) == pytest.approx(press / expected, rel=1e-6)


def test_calibrate_with_the_effect_says_it_is_unconfirmed_and_the_gate_refuses_it(
    magnetic, tmp_path, capsys
):
    pos, _, d = magnetic
    opt = CalibrationOptions(latitude_deg=LAT, effects=(G_SENS,))
    result = calibrate(pos, opt)
    check = effects_check(result, opt)
    assert check["trustworthy"] is False and check["effects"] == [G_SENS]
    # the same coefficient moves about as far as diagnose said
    name, shift = next(iter(check["core_shift"].items()))
    assert abs(shift) > CORE_SHIFT_SIGMA and name in d.core_shift
    assert effects_check(calibrate(pos, CalibrationOptions(latitude_deg=LAT)),
                         CalibrationOptions(latitude_deg=LAT)) is None  # fmt: skip
    refused = gate(result, None, GateConfig(), effects_check=check)
    assert not refused.accepted and any("NOT CONFIRMED" in r for r in refused.reasons)
    assert gate(result, None, GateConfig()).accepted  # nothing else refuses this fit
    allowed = gate(result, None, GateConfig(allow_unconfirmed_effects=True), effects_check=check)
    assert allowed.accepted and any("allowed (allow_unconfirmed_effects)" in r
                                    for r in allowed.reasons)  # fmt: skip
    # the command line: the JSON, the notes and the coefficients file say it
    csv, out = tmp_path / "mag.csv", tmp_path / "c.json"
    csv.write_text(pos.to_csv_text())
    args = ["calibrate", str(csv), "--latitude", "45", "--effects", f"+{G_SENS}", "-o", str(out)]
    assert main([*args, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["effects_check"]["trustworthy"] is False
    assert any(n.startswith("NOT CONFIRMED") for n in doc["notes"])
    assert json.loads(out.read_text())["metadata"]["unconfirmed_effects"] == [G_SENS]


def test_the_service_job_refuses_an_unconfirmed_effect(magnetic):
    from service.config import GateSettings
    from service.recalibration import calibration_job

    pos, _, _ = magnetic
    opt = CalibrationOptions(latitude_deg=LAT, effects=(G_SENS,))
    outcome = calibration_job(pos.columns, opt, None, GateSettings().model_dump())
    assert not outcome.accepted and any("NOT CONFIRMED" in r for r in outcome.reasons)
    assert outcome.document["effects_check"]["trustworthy"] is False
