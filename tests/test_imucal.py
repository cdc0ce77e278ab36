"""The two real imucal sessions (../shared/data/imucal): our answers against imucal's own Ferraris
calibrations of the same data, with no flags beyond --columns/--rate (issue 18).

- accelerometer scale factors within 3 reported sigma + 50 ppm of imucal's (both sessions);
- the calibration is a fixed point: its own output as --prior changes chi2_red by < 10 % and no
  coefficient by more than 1 sigma, and the JSON says "converged": true.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from recal.model.imucal import coefficients_from_imucal
from recal.model.reference import normal_gravity_g
from service.cli.main import main

COLUMNS = "gyro_x=gyr_x,gyro_y=gyr_y,gyro_z=gyr_z,accel_x=acc_x,accel_y=acc_y,accel_z=acc_z"
ANNOTATED_RATE_HZ = 204.8


def _run_json(capsys, args: list[str]) -> dict:
    assert main([*args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _imucal(shared: Path, name: str):
    doc = json.loads((shared / "imucal" / f"{name}.imucal_cal.json").read_text())
    return coefficients_from_imucal(doc, normal_gravity_g(45.0))  # calibrate's default latitude


@pytest.fixture(scope="module")
def annotated_positions(shared_data: Path, tmp_path_factory) -> str:
    """The annotated session in time order (its rows are grouped by part; time = samples /
    204.8 Hz, as its README says), through `recal positions`."""
    d = tmp_path_factory.mktemp("annotated")
    rows = list(csv.DictReader(open(shared_data / "imucal" / "annotated_session.csv")))
    rows.sort(key=lambda r: int(r["samples"]))
    rec = d / "annotated.csv"
    with open(rec, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"])
        for r in rows:
            w.writerow([int(r["samples"]) / ANNOTATED_RATE_HZ] + [r[k] for k in
                       ("acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z")])  # fmt: skip
    pos = d / "annotated_pos.csv"
    assert (
        main(["positions", str(rec), "--format", "csv", "--columns", COLUMNS, "-o", str(pos)]) == 0
    )
    return str(pos)


@pytest.fixture(scope="module")
def ferraris_positions(shared_data: Path, tmp_path_factory) -> str:
    d = tmp_path_factory.mktemp("ferraris")
    pos = d / "ferraris_pos.csv"
    rec = shared_data / "imucal" / "example_ferraris_session.csv"
    args = ["positions", str(rec), "--format", "csv", "--rate", "102.4", "--columns", COLUMNS]
    assert main([*args, "-o", str(pos)]) == 0
    return str(pos)


def _accel_scale_check(doc: dict, reference) -> None:
    k = np.array(doc["coefficients"]["accel"]["scale"])
    sd = np.array(doc["uncertainty"]["accel"]["scale"])
    ref = reference.values["accel.scale"]
    off_ppm = (k / ref - 1) * 1e6
    allowed_ppm = 3 * sd / ref * 1e6 + 50
    assert np.all(np.abs(off_ppm) <= allowed_ppm), (off_ppm.round(), allowed_ppm.round())


def test_annotated_session_accelerometer_scale_against_imucal(
    annotated_positions: str, shared_data: Path, capsys
) -> None:
    doc = _run_json(capsys, ["calibrate", annotated_positions, "--sensor", "accel"])
    _accel_scale_check(doc, _imucal(shared_data, "annotated_session"))
    # six faces cannot show misalignment: held, and its uncertainty is in the scale's
    assert set(doc["status"]["accel"]["misalignment"].values()) == {"held"}
    assert doc["held_uncertainty"]["sensor_class"] == "mems"


def test_ferraris_session_accelerometer_scale_against_imucal(
    ferraris_positions: str, shared_data: Path, capsys
) -> None:
    doc = _run_json(capsys, ["calibrate", ferraris_positions])
    _accel_scale_check(doc, _imucal(shared_data, "example_ferraris_session"))


def test_ferraris_calibration_is_a_fixed_point(ferraris_positions: str, tmp_path, capsys) -> None:
    first = tmp_path / "first.json"
    a = _run_json(capsys, ["calibrate", ferraris_positions, "-o", str(first)])
    assert a["converged"] is True, a["convergence"]
    b = _run_json(capsys, ["calibrate", ferraris_positions, "--prior", str(first)])
    assert b["converged"] is True, b["convergence"]
    assert abs(b["chi2_red"] / a["chi2_red"] - 1) < 0.10
    for sensor in ("gyro", "accel"):
        for key in ("scale", "bias"):
            x = np.array(a["coefficients"][sensor][key])
            y = np.array(b["coefficients"][sensor][key])
            sd = np.array(a["uncertainty"][sensor][key])
            assert np.all(np.abs(y - x) < sd), (sensor, key, (y - x) / sd)


WARMUP = str(Path(__file__).resolve().parents[1] / "docs" / "examples" / "warmup_plugin.py")


@pytest.mark.slow
def test_ferraris_misfit_is_named_and_adding_it_fits(ferraris_positions: str, capsys) -> None:
    """chi2_red above 3: diagnose points at a drift with time, names the accelerometer's warm-up
    drift, and calibrate with it halves chi2_red. The session's three 360-degree turns are
    declared closed, as the Ferraris protocol makes them (a MEMS gyro cannot check them by
    Earth rate).

    The gyro's g-sensitivity was suggested next until issue 35: it explains 30 % of the gyro's
    misfit, which is as well an excess independent on each window (model error of a hand-turned
    MEMS unit), and against that null its 9 parameters do not pay (delta IC +2.6): it is no
    longer suggested, and calibrate with the drift alone leaves chi2_red 3.05."""
    closed = ["--turn-closure", "0.1"]
    doc = _run_json(capsys, ["diagnose", ferraris_positions, *closed])
    assert doc["model_fails"] and "write it as a --plugin" in doc["verdict"]
    first = next(iter(doc["residual_correlations"]))  # strongest first
    assert first == "accel_norm vs time_h", doc["residual_correlations"]
    doc = _run_json(capsys, ["diagnose", ferraris_positions, "--plugin", WARMUP, *closed])
    suggested = doc["suggested_effects"]
    assert suggested[:1] == ["accel.bias_drift"], suggested
    g = next(c for c in doc["candidates"] if c["effect"] == "gyro.g_sensitivity")
    assert not g["significant"] and g["hypotheses"]["null"] == "noise" and g["delta_bic"] > 0
    effects = ",".join(f"+{e}" for e in suggested)
    fit = _run_json(capsys, ["calibrate", ferraris_positions, "--plugin", WARMUP,
                             "--effects", effects, *closed])  # fmt: skip
    base = _run_json(capsys, ["calibrate", ferraris_positions, *closed])
    assert fit["chi2_red"] <= 0.65 * base["chi2_red"] and fit["converged"] is True


@pytest.mark.slow
def test_xsens_misfit_is_named_and_adding_it_fits(shared_data: Path, tmp_path, capsys) -> None:
    """The Xsens MEMS recording: chi2_red 25 with the seed model; diagnose names the gyro's
    g-sensitivity, and calibrate with it fits to chi2_red <= 3."""
    pos = str(tmp_path / "xsens.csv")
    files = [str(shared_data / f"xsens_static_poses_{s}.txt") for s in ("acc", "gyro")]
    assert main(["positions", *files, "--format", "xsens-text", "-o", pos]) == 0
    site = ["--latitude", "57.834"]  # the recording's site (imu_tk)
    base = _run_json(capsys, ["calibrate", pos, *site])
    assert base["chi2_red"] > 3
    doc = _run_json(capsys, ["diagnose", pos, *site])
    assert doc["suggested_effects"][:1] == ["gyro.g_sensitivity"], doc["suggested_effects"]
    fit = _run_json(capsys, ["calibrate", pos, *site, "--effects", "+gyro.g_sensitivity"])
    assert fit["chi2_red"] <= 3.0 and fit["converged"] is True
