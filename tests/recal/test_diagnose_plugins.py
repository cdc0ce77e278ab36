"""Plugins as documented: candidates (never the baseline), checked on load, given the
attitude-free site context and extra CSV columns, recorded in the coefficients file."""

import json
from pathlib import Path

import numpy as np
import pytest

from recal.diagnose.effects import diagnose
from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.plugins import hidden_plugin, site_context, true_site_context
from recal.report.html import diagnosis_html
from recal.sim.simulate import design_orientations, simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.cli.common import load_plugin
from service.cli.main import main

FARADAY = Path(__file__).resolve().parents[2] / "docs" / "examples" / "faraday_plugin.py"
F_TRUE = np.array([0.04, -0.03, 0.05])  # deg/h per gauss


def _magnetic_positions(seed: int, design: str = "random", n: int | None = 24):
    (term,) = load_plugin(str(FARADAY))
    C = design_orientations(design, n, np.random.default_rng(seed))  # the simulator's draw
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.faraday"] = F_TRUE
    pos = simulate_positions(truth, design, n, 45.0, seed=seed,
                             hidden=[hidden_plugin(term, C, 45.0)])  # fmt: skip
    return term, pos, truth


def test_measured_site_context_matches_the_true_attitude():
    term, pos, truth = _magnetic_positions(seed=3)
    C = design_orientations("random", 24, np.random.default_rng(3))
    true = true_site_context(C, 45.0)
    got = site_context(pos, truth.values, 45.0, 0.0)
    for k in ("gravity_direction", "earth_rate_direction", "north", "east"):
        assert np.max(np.abs(got[k] - true[k])) < 2e-3, k  # misalignment-level error only


def test_plugin_without_effects_is_a_candidate_and_ranks_first():
    term, pos, _ = _magnetic_positions(seed=1)
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0, plugin_terms=[term]))
    assert d.baseline_effects == []
    assert "gyro.faraday" not in d.baseline.terms  # not folded into the baseline
    top = d.candidates[0]
    assert top.effect == "gyro.faraday" and top.significant, [
        (c.effect, c.delta_bic) for c in d.candidates[:3]
    ]
    assert d.suggested_effects[0] == "gyro.faraday" and d.final_chi2_red < 2 < d.chi2_red
    est = np.array(list(top.parameters.values()))
    sd = np.array(list(top.uncertainty.values()))
    assert np.all(np.abs(est - F_TRUE) < 4 * sd)
    # the report plots the residual against what drives the plugin: the site directions
    assert set(top.drivers) == {"north", "east", "gravity_direction"}
    page = diagnosis_html(d)
    assert "gravity direction x [body axes]" in page and "with gyro.faraday" in page


def test_cli_diagnose_with_plugin_and_no_effects(tmp_path, capsys):
    _, pos, _ = _magnetic_positions(seed=2)
    csv = tmp_path / "mag.csv"
    csv.write_text(pos.to_csv_text())
    rc = main(["diagnose", str(csv), "--latitude", "45", "--plugin", str(FARADAY), "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["candidates"][0]["effect"] == "gyro.faraday"
    assert doc["suggested_effects"][0] == "gyro.faraday"


def test_calibrate_with_the_plugin_removes_the_scale_error():
    term, pos, truth = _magnetic_positions(seed=0, design="random", n=36)
    K0 = truth.values["gyro.scale"]

    def scale_error_ppm(effects):
        r = calibrate(pos, CalibrationOptions(latitude_deg=45.0, plugin_terms=[term],
                                              effects=effects))  # fmt: skip
        K = r.theta[r.layout.term_slices()["gyro.scale"]]
        return np.abs(K / K0 - 1) * 1e6, r.uncertainty["gyro.scale"] / np.abs(K0) * 1e6

    plain, _ = scale_error_ppm([])
    fixed, sd = scale_error_ppm(["gyro.faraday"])
    assert plain.max() > 400  # the field leaks into the scale factors
    assert np.all(fixed < 4 * sd)


BAD_PLUGINS = {
    "no_dot": ('Bias1("gyrofoo", "gyro", ("a",), "1", (0.1,), (0.0,), "x")', "one dot"),
    "wrong_prefix": (
        'Bias1("accel.foo", "gyro", ("a",), "1", (0.1,), (0.0,), "x")',
        "must start with its sensor",
    ),
    "typical_len": (
        'Bias1("gyro.foo", "gyro", ("a",), "1", (0.1, 0.2), (0.0,), "x")',
        "typical must have one number per parameter",
    ),
    "shape": ('Wrong("gyro.foo", "gyro", ("a",), "1", (0.1,), (0.0,), "x")', "does not broadcast"),
    "undeclared": (
        'Reads("gyro.foo", "gyro", ("a",), "1", (0.1,), (0.0,), "x")',
        "not in its needs",
    ),
    "catalogue_name": (
        'Bias1("gyro.bias_drift", "gyro", ("a",), "1", (0.1,), (0.0,), "x")',
        "built-in",
    ),
}
BAD_HEADER = """
from dataclasses import dataclass
import numpy as np
from recal.model.terms import Term

@dataclass(frozen=True)
class Bias1(Term):
    def offset(self, p, ctx):
        return p[:, None, :1] * np.ones((1, 1, 3))

@dataclass(frozen=True)
class Wrong(Term):
    def offset(self, p, ctx):
        return np.zeros((5, 7))

@dataclass(frozen=True)
class Reads(Term):
    def offset(self, p, ctx):
        return p[:, None, :1] * ctx["mag_x"][None, :, None]
"""


@pytest.mark.parametrize("case", sorted(BAD_PLUGINS))
def test_malformed_plugin_is_exit_2_naming_file_term_and_problem(case, tmp_path, capsys):
    expr, message = BAD_PLUGINS[case]
    plugin = tmp_path / f"{case}.py"
    plugin.write_text(BAD_HEADER + f"\nTERMS = [{expr}]\n")
    csv = tmp_path / "pos.csv"
    csv.write_text(simulate_positions(CoefficientSet.seed_truth(), "24", seed=0).to_csv_text())
    rc = main(["diagnose", str(csv), "--latitude", "45", "--plugin", str(plugin)])
    err = capsys.readouterr().err
    assert rc == 2, err
    line = err.strip().splitlines()[-1]
    assert str(plugin) in line and message in line and "Traceback" not in err


def test_extra_csv_column_reaches_a_term(tmp_path):
    plugin = tmp_path / "magx.py"
    plugin.write_text(BAD_HEADER.replace('class Reads(Term)', 'class Reads(Term)') + (
        '\nTERMS = [Reads("gyro.magx", "gyro", ("a",), "deg/h/gauss", (0.05,), (0.0,), '
        '"bias from a magnetometer column", needs=frozenset({"mag_x"}))]\n'))  # fmt: skip
    (term,) = load_plugin(str(plugin))
    pos = simulate_positions(CoefficientSet.seed_truth(), "random", 30, 45.0, seed=4)
    rng = np.random.default_rng(0)
    mag = rng.uniform(-0.5, 0.5, len(pos))
    # the effect: every gyro axis reads a * mag_x (deg/h) in output units
    K = CoefficientSet.seed_truth().values["gyro.scale"]
    for i, ax in enumerate("xyz"):
        pos.columns[f"gyro_{ax}"] = pos.columns[f"gyro_{ax}"] + K[i] * 0.05 * mag
    with pytest.raises(RecalInputError, match="needs 'mag_x': not a column"):
        calibrate(pos, CalibrationOptions(latitude_deg=45.0, plugin_terms=[term],
                                          effects=["gyro.magx"]))  # fmt: skip
    (c,) = diagnose(pos, CalibrationOptions(latitude_deg=45.0, plugin_terms=[term])).candidates[-1:]
    assert c.effect == "gyro.magx" and not c.identifiable and "mag_x" in c.reason
    pos.columns["mag_x"] = mag
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0, plugin_terms=[term]))
    top = d.candidates[0]
    assert top.effect == "gyro.magx" and abs(top.parameters["a"] - 0.05) < 4 * top.uncertainty["a"]


def test_coefficients_file_records_its_plugins(tmp_path, capsys):
    _, pos, _ = _magnetic_positions(seed=5)
    csv = tmp_path / "mag.csv"
    csv.write_text(pos.to_csv_text())
    coeffs = tmp_path / "c.json"
    base = ["calibrate", str(csv), "--latitude", "45"]
    assert main([*base, "--plugin", str(FARADAY), "--effects", "+gyro.faraday",
                 "-o", str(coeffs)]) == 0  # fmt: skip
    doc = json.loads(coeffs.read_text())
    assert doc["metadata"]["plugins"]["gyro.faraday"].endswith("faraday_plugin.py")
    capsys.readouterr()
    assert main([*base, "--prior", str(coeffs)]) == 2
    err = capsys.readouterr().err
    assert "gyro.faraday" in err and "faraday_plugin.py" in err and "--plugin" in err
    assert main([*base, "--prior", str(coeffs), "--plugin", str(FARADAY)]) == 0
    assert "loaded but not fitted" in capsys.readouterr().err
