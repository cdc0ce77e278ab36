"""Acceptance (issue 18 item 5): a hand-held low-cost MEMS recording of our own making (raw
counts, 100 Hz, ten poses held 5-10 s by hand; recal.sim.session.simulate_handheld). Every pose is
used for the accelerometer, the summary names what was rejected and why, and calibrate fits the
accelerometer from all poses."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from recal.model.positions import Positions
from recal.sim.session import mems_truth, simulate_handheld
from service.cli.main import main

TRUTH_SEED = 11
SEED = 3  # 5 of the 10 poses tremble too much for the both-triad detector (5 windows before)


@pytest.fixture(scope="module")
def handheld(tmp_path_factory):
    """The recording as a CSV log in raw counts, and what recal positions made of it (once for
    the module: the tests only read it)."""
    tmp_path = tmp_path_factory.mktemp("handheld")
    truth = mems_truth(TRUTH_SEED)
    s = simulate_handheld(truth, n_poses=10, seed=SEED)
    log = tmp_path / "handheld.csv"
    data = np.column_stack([s.time_s, s.gyro_out, s.accel_out])
    header = "time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z"
    np.savetxt(log, data, delimiter=",", header=header, comments="", fmt=["%.2f"] + ["%d"] * 6)
    out, report = tmp_path / "pos.csv", tmp_path / "pos.html"
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr):
        rc = main(
            ["positions", str(log), "--format", "csv", "--report", str(report), "-o", str(out)]
        )
    err = stderr.getvalue()
    assert rc == 0, err
    return s, truth, out, report, err


def test_every_pose_is_used_for_the_accelerometer(handheld):
    s, _, out, _, err = handheld
    table = Positions.from_csv_text(out.read_text(), source=str(out))
    assert len(table) == s.n_holds == 10
    mid = 0.5 * (table.columns["start_s"] + table.columns["end_s"])
    hold = np.searchsorted(s.hold_start_s, mid) - 1
    assert hold.tolist() == list(range(10))  # one window per hold, inside it
    assert (table.columns["end_s"] <= s.hold_end_s[hold]).all()
    still = table.columns["gyro_still"]
    assert set(still.tolist()) == {0.0, 1.0} and int((still == 0).sum()) == 5
    assert "windows: 10 kept (5 with both triads still, 5 for the accelerometer only" in err
    assert "poses: 10 still stretches of the accelerometer seen, 10 used, 0 without" in err


def test_the_summary_says_what_was_rejected_and_why(handheld):
    s, _, out, report, err = handheld
    table = Positions.from_csv_text(out.read_text())
    lines = [x for x in err.splitlines() if "gyro not still (used for the accelerometer only)" in x]
    assert len(lines) == 5
    for i in np.flatnonzero(table.columns["gyro_still"] == 0):  # each one by its span
        span = f"{table.columns['start_s'][i]:.2f}-{table.columns['end_s'][i]:.2f} s"
        assert sum(span in x for x in lines) == 1, span
    page = report.read_text()
    assert page.count("<tr><td>gyro_not_still</td>") == 5
    assert "rejected: gyro not still (5)" in page
    assert "gyro not still (used for the accelerometer only)" in page  # the summary list


def test_the_accelerometer_is_calibrated_from_every_pose(handheld, capsys):
    _, truth, out, _, _ = handheld
    rc = main(["calibrate", str(out), "--sensor", "accel", "--latitude", "45", "--json"])
    text = capsys.readouterr()
    assert rc == 0, text.err
    doc = json.loads(text.out)
    assert doc["residuals"]["accel_norm"]["per_position"].__len__() == 10
    assert doc["status"]["accel"]["scale"] == ["estimated"] * 3
    for key in ("scale", "bias"):
        got = np.array(doc["coefficients"]["accel"][key])
        sd = np.array(doc["uncertainty"]["accel"][key])
        want = truth.values[f"accel.{key}"]
        assert np.all(np.abs(got - want) < 3.5 * sd), (key, got - want, sd)
    rel = np.array(doc["uncertainty"]["accel"]["scale"]) / truth.values["accel.scale"]
    assert np.all(rel < 5e-4)  # ten hand-held poses: scale to a few 1e-4


def test_handheld_gyro_is_calibrated_from_the_slews(handheld, capsys):
    """Both triads: the accelerometer from all poses, the gyro's scale from the slews (its
    Earth rate is far below its noise; 5 of its 10 windows tremble)."""
    _, truth, out, _, _ = handheld
    rc = main(["calibrate", str(out), "--latitude", "45", "--json"])
    text = capsys.readouterr()
    assert rc == 0, text.err
    doc = json.loads(text.out)
    assert doc["status"]["gyro"]["scale"] == ["estimated"] * 3
    got = np.array(doc["coefficients"]["gyro"]["scale"])
    assert np.all(np.abs(got / truth.values["gyro.scale"] - 1) < 0.01)  # truth within 2 % of 131
    assert doc["status"]["accel"]["scale"] == ["estimated"] * 3
