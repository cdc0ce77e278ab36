"""``recal drift``: text, --json and --report on simulated sessions (coefficients from ``recal
calibrate -o`` on 30 windows), and bad input as exit 2 with one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from service.cli.main import main

LAT = "45"


def run(capsys, *args) -> tuple[int, str, str]:
    rc = main(["drift", *map(str, args)])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """fit.csv (30 windows), COEFFS.json from calibrate -o, steady.csv and step.csv (30 new
    windows, the second with gyro x scale +600 ppm)."""
    d = tmp_path_factory.mktemp("drift")
    truth = CoefficientSet.seed_truth()
    fit = simulate_positions(truth, "random", 30, latitude_deg=45.0, seed=1002)
    (d / "fit.csv").write_text(fit.to_csv_text())
    steady = simulate_positions(truth, "random", 30, latitude_deg=45.0, seed=2002)
    (d / "steady.csv").write_text(steady.to_csv_text())
    changed = truth.copy()
    changed.values["gyro.scale"][0] *= 1 + 600e-6
    step = simulate_positions(changed, "random", 30, latitude_deg=45.0, seed=2002)
    (d / "step.csv").write_text(step.to_csv_text())
    assert main(["calibrate", str(d / "fit.csv"), "--latitude", LAT, "-o", str(d / "c.json")]) == 0
    return d


def test_json_steady_and_step(files, capsys):
    rc, out, err = run(capsys, files / "steady.csv", "--coefficients", files / "c.json",
                       "--latitude", LAT, "--json")  # fmt: skip
    assert rc == 0
    steady = json.loads(out)
    assert steady["alarm_window"] is None
    assert len(steady["windows"]) == 30
    assert all(w["statistic"] < steady["threshold"] for w in steady["windows"])
    assert 5 < steady["threshold"] <= steady["threshold_bound"]
    rc, out, err = run(capsys, files / "step.csv", "--coefficients", files / "c.json",
                       "--latitude", LAT, "--json")  # fmt: skip
    assert rc == 0
    step = json.loads(out)
    k = step["alarm_window"]
    print(f"\nCLI: +600 ppm gyro x scale, alarm at row {k}: {step['suspects'][0]['description']}")
    assert k is not None and k < 15
    assert step["windows"][k]["statistic"] > step["threshold"]
    assert all(w["statistic"] <= step["threshold"] for w in step["windows"][:k])
    assert step["suspects"][0]["coefficient"] == "gyro.scale.Kx"
    assert step["suspects"][0]["description"].startswith("gyro x scale, about +")
    assert step["notes"] == ["coefficient uncertainty from the file's covariance"]


def test_text_and_report(files, capsys, tmp_path):
    report = tmp_path / "drift.html"
    rc, out, err = run(capsys, files / "step.csv", "--coefficients", files / "c.json",
                       "--latitude", LAT, "--report", report)  # fmt: skip
    assert rc == 0
    assert "first alarm: row" in out and "drift looks like: gyro x scale, about +" in out
    assert "threshold" in out and len(out.splitlines()) > 30
    page = report.read_text()
    assert page.startswith("<!doctype html>") and "<svg" in page
    assert "threshold" in page and "http://" not in page.replace("http://www.w3.org", "")
    assert "wrote the report" in err


def test_calibrate_json_output_is_accepted(files, capsys, tmp_path):
    assert main(["calibrate", str(files / "fit.csv"), "--latitude", LAT, "--json"]) == 0
    cal = tmp_path / "cal.json"
    cal.write_text(capsys.readouterr()[0])
    rc, out, _ = run(capsys, files / "steady.csv", "--coefficients", cal, "--latitude", LAT,
                     "--json")  # fmt: skip
    assert rc == 0 and json.loads(out)["alarm_window"] is None


def _one_line_error(capsys, *args) -> str:
    rc, out, err = run(capsys, *args)
    assert rc == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[-1]


def test_bad_input_is_exit_2_with_one_line(files, capsys, tmp_path):
    c = files / "c.json"
    # a positions file missing a column of a triad
    text = (files / "steady.csv").read_text().splitlines()
    header = text[0].split(",")
    drop = header.index("gyro_y")
    cut = [",".join(v for i, v in enumerate(row.split(",")) if i != drop) for row in text]
    bad = tmp_path / "cut.csv"
    bad.write_text("\n".join(cut) + "\n")
    assert "gyro_y" in _one_line_error(capsys, bad, "--coefficients", c, "--latitude", LAT)
    # coefficients without the triad of an accelerometer-only file
    data = json.loads(c.read_text())
    gyro_only = {k: v for k, v in data.items() if k != "accel"}
    gyro_only["uncertainty"] = {"gyro": data["uncertainty"]["gyro"]}
    g = tmp_path / "gyro.json"
    g.write_text(json.dumps(gyro_only))
    pos = np.genfromtxt(files / "steady.csv", delimiter=",", names=True)
    keep = [n for n in pos.dtype.names if not n.startswith("gyro")]
    acc = tmp_path / "accel.csv"
    acc.write_text(",".join(keep) + "\n" + "\n".join(
        ",".join(repr(float(row[n])) for n in keep) for row in pos) + "\n")  # fmt: skip
    assert "no coefficients for the triad" in _one_line_error(
        capsys, acc, "--coefficients", g, "--latitude", LAT
    )
    # a triad without its bias, invalid JSON, a missing file
    no_bias = json.loads(c.read_text())
    del no_bias["gyro"]["bias"]
    nb = tmp_path / "nb.json"
    nb.write_text(json.dumps(no_bias))
    assert "gyro.bias missing" in _one_line_error(
        capsys, files / "steady.csv", "--coefficients", nb, "--latitude", LAT
    )
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    assert "not valid JSON" in _one_line_error(
        capsys, files / "steady.csv", "--coefficients", broken, "--latitude", LAT
    )
    assert "does not exist" in _one_line_error(
        capsys, tmp_path / "none.csv", "--coefficients", c, "--latitude", LAT
    )
    assert "--false-alarm-windows" in _one_line_error(
        capsys, files / "steady.csv", "--coefficients", c, "--false-alarm-windows", "1",
        "--latitude", LAT,
    )  # fmt: skip


def test_a_wrong_latitude_alarms_at_once_and_says_why(files, capsys):
    rc, out, _ = run(capsys, files / "steady.csv", "--coefficients", files / "c.json",
                     "--latitude", "30", "--json")  # fmt: skip
    doc = json.loads(out)
    assert rc == 0 and doc["alarm_window"] == 0
    assert any("check --latitude" in n for n in doc["notes"])
