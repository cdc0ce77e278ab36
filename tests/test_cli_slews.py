"""``recal positions`` keeps the slews beside the CSV; ``recal calibrate`` uses them."""

from __future__ import annotations

import json

import numpy as np

from recal.coefficients import CoefficientSet
from recal.session import simulate_session
from recal.simulate import NoiseSpec
from recal.slews import Slews
from service.cli.main import main

ACC = "xsens_static_poses_acc.txt"
GYRO = "xsens_static_poses_gyro.txt"
XSENS_LATITUDE = 57.834


def test_xsens_gyro_is_calibrated_from_the_slews(shared_data, tmp_path, capsys):
    out = tmp_path / "x.csv"
    args = [str(shared_data / ACC), str(shared_data / GYRO), "--format", "xsens-text"]
    assert main(["positions", *args, "-o", str(out)]) == 0
    err = capsys.readouterr().err
    side = tmp_path / "x.slews.npz"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv", "x.slews.npz"]
    assert "kept 37 slews" in err and "dropped 0" in err
    slews = Slews.from_npz_bytes(side.read_bytes())
    assert len(slews) == 37 and side.stat().st_size < 200_000
    cal = ["calibrate", str(out), "--latitude", str(XSENS_LATITUDE), "--json"]
    assert main(cal) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["sensor"] == "both"
    assert set(doc["status"]["gyro"]["misalignment"].values()) == {"estimated"}
    assert doc["status"]["gyro"]["scale"] == ["estimated"] * 3
    sigma = np.array(doc["uncertainty"]["gyro"]["scale"])
    scale = np.array(doc["coefficients"]["gyro"]["scale"])
    assert np.all(sigma / scale < 3e-3)  # counts per deg/h, ~0.0232 (1/43 deg/h per count)
    assert np.allclose(scale, 0.0231, rtol=0.02)
    slew = doc["residuals"]["slew"]
    assert (
        slew["slews"] == 37 and slew["noise_floor"] > 0 and slew["rms_after"] < slew["rms_before"]
    )
    assert main([*cal, "--no-slews"]) == 0  # as before the slews: the gyro is skipped
    doc = json.loads(capsys.readouterr().out)
    assert doc["sensor"] == "accel" and "slew" not in doc["residuals"]
    side.unlink()
    assert main([*cal, "--slews"]) == 2
    assert "no slews file" in capsys.readouterr().err


def test_a_slew_with_a_lost_frame_is_dropped_and_counted(tmp_path, capsys):
    s = simulate_session(CoefficientSet.seed_truth(), "24", latitude_deg=40.0, seed=2,
                         rate_hz=100.0, window_s=6.0, slew_s=3.0, first_hold_s=12.0,
                         noise=NoiseSpec(arw_deg_rt_h=0.0005, vrw_ug_rt_hz=20.0))  # fmt: skip
    keep = np.ones(len(s), dtype=bool)
    keep[int(s.hold_last[3]) + 150] = False  # one frame lost in the middle of slew 3
    log = tmp_path / "log.csv"
    header = "time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z"
    rows = np.column_stack([s.time_s, s.gyro_out, s.accel_out])[keep]
    np.savetxt(log, rows, delimiter=",", header=header, comments="", fmt="%.17g")
    out = tmp_path / "p.csv"
    assert main(["positions", str(log), "--format", "csv", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "dropped 1 (lost_frames 1)" in err
    slews = Slews.from_npz_bytes((tmp_path / "p.slews.npz").read_bytes())
    assert slews.dropped["lost_frames"] == 1 and len(slews) == 22 and 3 not in slews.first
    assert main(["calibrate", str(out), "--latitude", "40", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert any("1 slew(s) dropped" in n for n in doc["notes"])
    assert doc["positions"] == 24  # its two windows still serve as positions
