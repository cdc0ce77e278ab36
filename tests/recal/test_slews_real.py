"""The gyro from the slews on a real hand-turned MEMS session (imucal's Ferraris example,
../shared/data/imucal): scale within 1000 ppm of imucal's with its three 360-degree turns declared
closed (--turn-closure 0.1); a MEMS gyro cannot check them by Earth rate, so by default they are
not assumed closed and the face flips alone give the scale, off by more but with an honest sigma."""

import json

import numpy as np

from service.cli.main import main

RATE_HZ = 102.4
COLUMNS = "gyro_x=gyr_x,gyro_y=gyr_y,gyro_z=gyr_z,accel_x=acc_x,accel_y=acc_y,accel_z=acc_z"


def _imucal_gyro_scale_per_deg_h(path) -> np.ndarray:
    """imucal's gyr_raw = K_g R_g gyr + ...: our K_i is (K_g R_g)_ii, in deg/s per deg/s ->
    output per deg/h."""
    cal = json.loads(path.read_text())
    return np.diag(np.array(cal["K_g"]) @ np.array(cal["R_g"])) / 3600.0


def test_ferraris_gyro_scale_from_the_slews_matches_imucal(shared_data, tmp_path, capsys):
    data = shared_data / "imucal"
    pos = tmp_path / "fer.csv"
    args = ["positions", str(data / "example_ferraris_session.csv"), "--format", "csv"]
    assert main([*args, "--rate", str(RATE_HZ), "--columns", COLUMNS, "-o", str(pos)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(pos), "--turn-closure", "0.1", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    ref = _imucal_gyro_scale_per_deg_h(data / "example_ferraris_session.imucal_cal.json")
    scale = np.array(doc["coefficients"]["gyro"]["scale"])
    sigma = np.array(doc["uncertainty"]["gyro"]["scale"])
    ppm = (scale / ref - 1.0) * 1e6
    assert np.all(np.abs(ppm) < 1000), ppm  # measured -220/+170/-164 (was -1755/+8091/-2289)
    assert np.all(np.abs(scale - ref) < 3 * sigma)  # the 1-sigma is honest
    assert np.all(sigma / ref < 2e-3)  # and says something (measured ~700 ppm)
    # the three 360-degree turns about the vertical are found and, declared, taken as closed
    closure = doc["residuals"]["closure"]
    assert closure["slews"] == [7, 9, 11] and closure["turns"] == [-1, -1, -1]
    assert closure["how"] == ["declared"] * 3 and np.allclose(closure["closure_sigma_deg"], 0.1)
    declared = [n for n in doc["notes"] if "a closed turn (-1 x 360 deg), declared" in n]
    assert len(declared) == 3 and all("not observable" in n for n in declared)
    # the face flips' misfit is carried by an unmodelled per-slew error, said in the notes
    assert any("unmodelled error of" in n for n in doc["notes"])
    assert any("from Earth rate in the still windows" in n for n in doc["notes"])


def test_by_default_the_turns_are_not_closed_and_the_flips_alone_are_off(
    shared_data, tmp_path, capsys
):
    """The slew invariant cannot see a turn about the vertical, and this MEMS gyro cannot check
    a turn's closure by Earth rate: without --turn-closure the turns are not assumed closed, the
    notes and the JSON say why, and the scale comes from the hand-made face flips only: off by
    more, but within 3 of its (larger) reported sigma."""
    data = shared_data / "imucal"
    pos = tmp_path / "fer.csv"
    args = ["positions", str(data / "example_ferraris_session.csv"), "--format", "csv"]
    assert main([*args, "--rate", str(RATE_HZ), "--columns", COLUMNS, "-o", str(pos)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(pos), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "closure" not in doc["residuals"]
    cands = doc["turn_closure"]["candidates"]
    assert [c["slew"] for c in cands] == [7, 9, 11] and not any(c["closed"] for c in cands)
    assert doc["turn_closure"]["declared_sigma_deg"] is None
    assert all("not observable" in c["reason"] and "--turn-closure" in c["reason"] for c in cands)
    assert sum("not taken as a closed turn" in n for n in doc["notes"]) == 3
    ref = _imucal_gyro_scale_per_deg_h(data / "example_ferraris_session.imucal_cal.json")
    scale = np.array(doc["coefficients"]["gyro"]["scale"])
    sigma = np.array(doc["uncertainty"]["gyro"]["scale"])
    assert np.abs(scale / ref - 1.0).max() > 1e-3  # measured -2883/+11913/-2039 ppm
    assert np.all(np.abs(scale - ref) < 3 * sigma)  # at 2788/11756/1957 ppm 1-sigma
