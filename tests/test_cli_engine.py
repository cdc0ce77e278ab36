"""The recal simulate / calibrate command line: JSON contract and bad input."""

import json
import subprocess
import sys

import pytest

from service.cli.main import main


@pytest.fixture(scope="module")
def positions_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("sim") / "pos.csv"
    assert main(["simulate", "--seed", "3", "--latitude", "52", "-o", str(path)]) == 0
    return path


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def test_calibrate_json_contract(positions_csv, capsys):
    capsys.readouterr()
    assert main(["calibrate", str(positions_csv), "--latitude", "52", "--json"]) == 0
    out = capsys.readouterr().out
    doc = json.loads(out)  # stdout is one JSON object and nothing else
    for key in ("coefficients", "status", "uncertainty", "observability", "residuals"):
        assert key in doc
    assert doc["observability"]["verdict"] == "partial"
    assert set(doc["coefficients"]["gyro"]) == {"scale", "bias", "misalignment"}
    assert doc["status"]["accel"]["quadratic"] == ["estimated"] * 3
    assert set(doc["status"]["gyro"]["misalignment"]) == {"Exz", "Exy", "Eyz", "Eyx", "Ezy", "Ezx"}
    r = doc["residuals"]["gyro_norm"]
    assert r["rms_after"] < r["rms_before"] and r["rms_after"] < 2 * r["noise_floor"]


def test_calibrate_writes_a_prior_that_round_trips(positions_csv, tmp_path, capsys):
    out = tmp_path / "coeffs.json"
    assert main(["calibrate", str(positions_csv), "--latitude", "52", "-o", str(out)]) == 0
    first = json.loads(out.read_text())
    out2 = tmp_path / "coeffs2.json"
    args = ["calibrate", str(positions_csv), "--latitude", "52", "--prior", str(out)]
    assert main(args + ["-o", str(out2)]) == 0
    second = json.loads(out2.read_text())
    # starting from its own answer the fit stays put (weights are re-propagated at the prior,
    # so agreement is to a small fraction of the 1-sigma of ~0.056 counts/(deg/h))
    assert second["gyro"]["scale"] == pytest.approx(first["gyro"]["scale"], abs=1e-3)
    assert second["accel"]["bias"] == pytest.approx(first["accel"]["bias"], abs=1e-7)
    assert "held" not in capsys.readouterr().err


BAD = {
    "missing column": ("start_s,gyro_x\n0,1\n", "missing column(s) gyro_y, gyro_z"),
    "nan cell": (
        "gyro_x,gyro_y,gyro_z\n" + "1,2,3\n" * 5 + "1,nan,3\n" + "1,2,3\n" * 10,
        "row 7, column 'gyro_y' is NaN or infinite",
    ),
    "non-numeric": (
        "gyro_x,gyro_y,gyro_z\n1,2,abc\n",
        "row 2, column 'gyro_z': 'abc' is not a number",
    ),
    "empty": ("", "file is empty"),
    "header only": ("gyro_x,gyro_y,gyro_z\n", "no data rows"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_positions_files(case, tmp_path, capsys):
    text, message = BAD[case]
    path = tmp_path / "bad.csv"
    path.write_text(text)
    out = tmp_path / "never.json"
    assert main(["calibrate", str(path), "--latitude", "10", "-o", str(out)]) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_too_few_positions(tmp_path, capsys):
    """Rank decides, not counting: 5 gyro positions cannot show 9 directions (a partial
    calibration, the rank in the note), 9 are exactly determined (estimated, and the output
    says the fit is unchecked)."""
    few, exact = tmp_path / "few.csv", tmp_path / "exact.csv"
    for path, n in ((few, 5), (exact, 9)):
        args = ["simulate", "--design", "random", "--positions", str(n), "--sensor", "gyro"]
        assert main([*args, "-o", str(path)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(few)]) == 0  # a partial design succeeds (docs/reference.md#cli)
    out = capsys.readouterr().out
    assert "partial calibration" in out and "rank 5 of 12" in out
    assert main(["calibrate", str(exact)]) == 0
    out = capsys.readouterr().out
    assert "exactly determined" in out


def test_degenerate_heading_only_design(tmp_path, capsys):
    path = tmp_path / "vessel.csv"
    assert main(["simulate", "--design", "vessel", "--positions", "30", "-o", str(path)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(path), "--latitude", "45"]) == 0  # partial, Kz held
    out = capsys.readouterr().out
    assert "partial calibration" in out and "gyro.scale.Kz" in out


def test_calibrate_json_gives_the_heading_error_before_and_after(tmp_path, capsys):
    """A hull-fixed unit with a prior of 0.01 deg/h: the "navigation" block and the report."""
    path, truth = tmp_path / "vessel.csv", tmp_path / "truth.json"
    assert main(["simulate", "--design", "vessel", "--positions", "24", "--seed", "1",
                 "-o", str(path), "--truth-out", str(truth)]) == 0  # fmt: skip
    prior = json.loads(truth.read_text())  # within 100 ppm, 0.01 deg/h, 20 ug, 0.1 mrad
    mis = dict.fromkeys(prior["gyro"]["misalignment"], 1e-4)
    prior["uncertainty"] = {
        "gyro": {"scale": [k * 1e-4 for k in prior["gyro"]["scale"]], "bias": [0.01] * 3,
                 "misalignment": mis},
        "accel": {"scale": [1e-4] * 3, "bias": [2e-5] * 3, "misalignment": mis,
                  "quadratic": [1e-5] * 3},
    }  # fmt: skip
    (tmp_path / "prior.json").write_text(json.dumps(prior))
    capsys.readouterr()
    report = tmp_path / "cal.html"
    args = ["calibrate", str(path), "--latitude", "45", "--prior", str(tmp_path / "prior.json")]
    assert main([*args, "--json", "--report", str(report)]) == 0
    doc = json.loads(capsys.readouterr().out)
    for key in ("coefficients", "status", "uncertainty", "observability", "residuals"):
        assert key in doc  # the stable keys stay
    nav = doc["navigation"]
    assert nav["before"]["from"] == f"the prior {tmp_path / 'prior.json'}"
    assert nav["before"]["heading_error_deg_rms"] == pytest.approx(0.0539, abs=1e-4)
    assert nav["after"]["heading_error_deg_rms"] < nav["before"]["heading_error_deg_rms"]
    assert nav["after"]["heading_error_deg_worst"] >= nav["after"]["heading_error_deg_rms"]
    assert nav["after"]["position_error_nmi_1sigma"] > 0
    assert "Navigation</b>: gyrocompass heading error" in report.read_text()
    assert main(args) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"navigation: {nav['summary']}"


def test_unreadable_inputs(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "nope.csv"), "--latitude", "0"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["calibrate", str(tmp_path), "--latitude", "0"]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_bad_prior_json(positions_csv, tmp_path, capsys):
    prior = tmp_path / "prior.json"
    prior.write_text("{not json")
    assert main(["calibrate", str(positions_csv), "--prior", str(prior)]) == 2
    assert "not valid JSON" in capsys.readouterr().err


def test_subprocess_exit_code_and_no_traceback(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("accel_x,accel_y\n1,2\n")
    proc = subprocess.run(
        [sys.executable, "-m", "service.cli.main", "calibrate", str(bad)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stdout == ""
    assert "missing column(s) accel_z" in proc.stderr


PLUGIN = '''
from dataclasses import dataclass
from recal.model.terms import Term


@dataclass(frozen=True)
class CrossBias(Term):
    """A user's own effect: z bias proportional to the x input."""

    def nonlinear(self, p, x, ctx):
        out = 0 * x
        out[..., 2] = p[:, None, 0] * x[..., 0]
        return out


TERMS = [CrossBias("gyro.cross_bias", "gyro", ("c",), "1", (1e-4,), (0.0,), "z bias from x rate")]
'''


def test_plugin_term_is_fitted_without_touching_the_solvers(positions_csv, tmp_path, capsys):
    plugin = tmp_path / "my_effect.py"
    plugin.write_text(PLUGIN)
    args = ["calibrate", str(positions_csv), "--latitude", "52", "--sensor", "gyro", "--json"]
    assert main([*args, "--plugin", str(plugin), "--effects", "+gyro.cross_bias"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "gyro.cross_bias" in doc["coefficients"]["effects"]
    assert doc["status"]["effects"]["gyro.cross_bias"]["c"] in ("estimated", "held")
    broken = tmp_path / "broken.py"
    broken.write_text("raise RuntimeError('oops')\n")
    assert main([*args, "--plugin", str(broken)]) == 2
    assert "failed to load: RuntimeError: oops" in capsys.readouterr().err
    assert main([*args, "--effects", "+gyro.nonsense"]) == 2
    assert "unknown effect 'gyro.nonsense'" in capsys.readouterr().err


def test_calibrate_html_report(positions_csv, tmp_path, capsys):
    report = tmp_path / "cal.html"
    assert main(["calibrate", str(positions_csv), "--latitude", "52", "--report", str(report)]) == 0
    page = report.read_text()
    assert page.startswith("<!doctype html>") and page.count("<svg") == 4  # 3 invariants + SVD
    assert "gyro.misalignment.Exz" in page and "estimated (sum only)" in page
    names = ("http://www.w3.org/2000/svg", "http://www.w3.org/1999/xlink")  # SVG namespaces
    assert "http" not in page.replace(names[0], "").replace(names[1], "")  # self-contained
    assert (report.stat().st_mode & 0o777) != 0o600  # shareable, not mkstemp's private mode


def test_cli_method_list_matches_the_engine():
    from recal.solve.calibrate import METHODS
    from service.cli import calibrate as cli

    assert cli.METHODS == METHODS


def test_calibrate_ages_the_held_coefficients_with_a_fleet_prior(tmp_path, capsys):
    """``--fleet-prior FLEET.json --prior-age-months M`` with ``--prior``: the held accel
    quadratic carries the fleet's change over M months (issue 28); a newer format is exit 2."""
    import json

    from recal.fleet.prior import CoefficientAgeing, FleetPrior
    from recal.model.coefficients import CoefficientSet
    from recal.sim.simulate import simulate_positions

    truth = CoefficientSet.seed_truth()
    positions = tmp_path / "p.csv"
    positions.write_text(simulate_positions(truth, design="random", n_positions=6).to_csv_text())
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps(truth.to_json_dict()))
    figure = {f"accel.quadratic.K2{a}": CoefficientAgeing(2e-5, 1e-6, False, 80, 900)
              for a in "xyz"}  # fmt: skip
    fleet = FleetPrior("KVH-1750", 4, "2026-11-27T00:00:00Z", figure)
    path = tmp_path / "fleet.json"
    path.write_text(json.dumps(fleet.to_json_dict()))
    base = ["calibrate", str(positions), "--latitude", "45", "--prior", str(prior), "--json"]
    assert main([*base, "--fleet-prior", str(path), "--prior-age-months", "9"]) == 0
    held = json.loads(capsys.readouterr().out)["held_uncertainty"]
    assert held["fleet_prior"]["version"] == 4 and held["fleet_prior"]["months"] == 9.0
    assert "fleet prior KVH-1750 v4 over 9 months" in held["prior_sigma_source"]["accel.quadratic"]
    assert main([*base, "--fleet-prior", str(path)]) == 2
    assert "go together" in capsys.readouterr().err
    path.write_text(json.dumps({**fleet.to_json_dict(), "format": "recal.fleet_prior/3"}))
    assert main([*base, "--fleet-prior", str(path), "--prior-age-months", "9"]) == 2
    assert "is newer than this recal reads" in capsys.readouterr().err
