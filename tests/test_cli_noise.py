"""``recal noise``: per-axis random walk, bias instability and correlation time of the still
stretches, as text, --json and --report, on a simulated recording and on imucal's session."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.signal import lfilter

from service.cli.main import main

RATE = 100.0
WHITE = np.array([0.02, 0.03, 0.04, 0.5, 0.6, 0.7])  # per-sample sigma, output units
GM_SIGMA, GM_TAU_S = 0.15, 3.0  # on gyro_x


def write_log(path, columns: dict[str, np.ndarray]) -> None:
    names = list(columns)
    table = np.column_stack([columns[n] for n in names])
    np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt="%.10g")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Six 40 s holds with 3 s of swinging between them, white noise on every axis and a
    Gauss-Markov process on gyro_x."""
    rng = np.random.default_rng(4)
    hold, slew = int(40 * RATE), int(3 * RATE)
    n = 6 * hold + 5 * slew
    x = WHITE * rng.standard_normal((n, 6))
    phi = np.exp(-1 / (GM_TAU_S * RATE))
    e = rng.standard_normal(n) * GM_SIGMA * np.sqrt(1 - phi * phi)
    x[:, 0] += lfilter([1.0], [1, -phi], e, zi=[phi * GM_SIGMA * rng.standard_normal()])[0]
    x[:, 5] += 1000.0  # gravity, in output units
    for k in range(5):
        s = slice(k * (hold + slew) + hold, (k + 1) * (hold + slew))
        swing = 50.0 * np.sin(np.linspace(0, 2 * np.pi, slew))
        x[s] += swing[:, None]
    path = tmp_path_factory.mktemp("noise") / "log.csv"
    cols = {"time_s": np.arange(n) / RATE}
    cols.update(
        {
            f"{s}_{a}": x[:, 3 * i + j]
            for i, s in enumerate(("gyro", "accel"))
            for j, a in enumerate("xyz")
        }
    )
    write_log(path, cols)
    return path


def run(capsys, *args) -> tuple[int, str, str]:
    rc = main(["noise", *map(str, args)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_json_recovers_the_simulated_noise(recording, capsys):
    rc, out, _ = run(
        capsys, recording, "--format", "csv", "--json", "--units", "gyro=deg/s,accel=m/s^2"
    )
    assert rc == 0
    doc = json.loads(out)
    assert doc["still_stretches"] >= 6  # the Gauss-Markov wander may split a hold
    assert doc["still_duration_s"] > 220
    names = [a["name"] for a in doc["axes"]]
    assert names == ["gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"]
    white = np.array([a["white"] for a in doc["axes"]])
    np.testing.assert_allclose(white[1:], WHITE[1:] / np.sqrt(RATE), rtol=0.05)
    gx = doc["axes"][0]
    assert gx["correlation_time_s"] == pytest.approx(GM_TAU_S, rel=0.5)
    assert gx["gauss_markov_sigma"] == pytest.approx(GM_SIGMA, rel=0.35)
    assert gx["white"] == pytest.approx(WHITE[0] / np.sqrt(RATE), rel=0.1)
    assert all(a["correlation_time_s"] is None for a in doc["axes"][1:])
    # deg/s x sqrt(s) -> deg/sqrt(h): x 60; m/s^2 x sqrt(s) -> m/s/sqrt(h): x 60
    assert doc["axes"][1]["white_usual"] == pytest.approx(60 * doc["axes"][1]["white"])
    assert doc["axes"][4]["white_usual"] == pytest.approx(60 * doc["axes"][4]["white"])
    # bias instability: the minimum Allan deviation / 0.664, above the white level there
    for a in doc["axes"]:
        floor = a["white"] / np.sqrt(a["bias_instability_tau_s"])
        assert a["bias_instability"] >= floor


def test_text_and_report(recording, tmp_path, capsys):
    page = tmp_path / "noise.html"
    rc, out, err = run(capsys, recording, "--format", "csv", "--report", page)
    assert rc == 0
    lines = out.strip().splitlines()
    assert len(lines) == 7 and lines[0].startswith("gyro_x: angle random walk")
    assert lines[3].startswith("accel_x: velocity random walk")
    assert "correlation time 3" in lines[0] or "correlation time 2" in lines[0]
    assert "still stretches, 2" in lines[-1] and "at 100 Hz" in lines[-1]
    html = page.read_text()
    assert html.count("<svg") == 6 and "http" not in html.split("<svg")[0]
    assert "1-sigma confidence" in html and "Gauss-Markov" in html
    assert "wrote the report" in err


def test_no_still_stretch_is_exit_2(tmp_path, capsys):
    t = np.arange(3000) / RATE
    swing = 50.0 * np.sin(2 * np.pi * 0.7 * t)
    cols = {"time_s": t}
    cols.update(
        {f"{s}_{a}": swing * (1 + j) for s in ("gyro", "accel") for j, a in enumerate("xyz")}
    )
    write_log(tmp_path / "moving.csv", cols)
    rc, out, err = run(capsys, tmp_path / "moving.csv", "--format", "csv",
                       "--threshold-k", "1", "--min-duration", "5")  # fmt: skip
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and "no still stretch" in err


def test_bad_units_and_missing_file_are_exit_2(recording, tmp_path, capsys):
    rc, _, err = run(capsys, recording, "--format", "csv", "--units", "gyro=furlongs")
    assert rc == 2 and "--units" in err
    rc, _, err = run(capsys, tmp_path / "absent.csv", "--format", "csv")
    assert rc == 2 and "does not exist" in err


def test_annotated_session(shared_data, tmp_path, capsys):
    """imucal's annotated session (raw counts, 204.8 Hz): white noise, six faces."""
    raw = np.genfromtxt(shared_data / "imucal" / "annotated_session.csv", delimiter=",",
                        names=True, dtype=None, encoding=None)  # fmt: skip
    raw = raw[np.argsort(raw["samples"], kind="stable")]
    cols = {"time_s": raw["samples"] / 204.8}
    cols.update({f"gyro_{a}": raw[f"gyr_{a}"].astype(float) for a in "xyz"})
    cols.update({f"accel_{a}": raw[f"acc_{a}"].astype(float) for a in "xyz"})
    write_log(tmp_path / "ann.csv", cols)
    rc, out, _ = run(capsys, tmp_path / "ann.csv", "--format", "csv", "--json")
    assert rc == 0
    doc = json.loads(out)
    assert doc["still_stretches"] == 6
    assert doc["sample_rate_hz"] == pytest.approx(204.8)
    # white level = the per-sample std / sqrt(rate): 2.7-8 counts at 204.8 Hz
    white = np.array([a["white"] for a in doc["axes"]])
    assert ((white > 2.0 / np.sqrt(204.8)) & (white < 9.0 / np.sqrt(204.8))).all()
    assert all(a["units"] is None and "white_usual" not in a for a in doc["axes"])
