"""``recal positions`` keeps the slews beside the CSV; ``recal calibrate`` uses them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recal.detect.slew_data import Slews
from recal.model.coefficients import CoefficientSet
from recal.sim.session import axis_angle, simulate_session
from recal.sim.simulate import NoiseSpec
from service.cli.main import main

ACC = "xsens_static_poses_acc.txt"
GYRO = "xsens_static_poses_gyro.txt"
XSENS_LATITUDE = 57.834


@pytest.mark.slow
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
    # the slews misfit (chi2_red ~10 on their window noise): an unmodelled per-slew error is
    # estimated from it, and the misalignment directions it leaves below their typical change
    # are held (1 of 6 in the measured run)
    assert any("unmodelled error of" in n for n in doc["notes"])
    status = list(doc["status"]["gyro"]["misalignment"].values())
    assert status.count("estimated") >= 4
    assert doc["status"]["gyro"]["scale"] == ["estimated"] * 3
    sigma = np.array(doc["uncertainty"]["gyro"]["scale"])
    scale = np.array(doc["coefficients"]["gyro"]["scale"])
    assert np.all(sigma / scale < 6e-3)  # counts per deg/h, ~0.0232 (1/43 deg/h per count)
    assert np.allclose(scale, 0.0231, rtol=0.02)
    slew = doc["residuals"]["slew"]
    assert (
        slew["slews"] == 37 and slew["noise_floor"] > 0 and slew["rms_after"] < slew["rms_before"]
    )
    # diagnose sees the same data: the slew invariant is among the ones it checks
    assert main(["diagnose", str(out), "--latitude", str(XSENS_LATITUDE), "--json"]) == 0
    diag = json.loads(capsys.readouterr().out)
    slew_row = next(i for i in diag["invariants"] if i["name"] == "slew")
    assert slew_row["unit"] == "rad" and slew_row["rms"] > slew_row["noise_floor"] > 0
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


def test_known_rotations_tie_the_gyro_to_the_case(tmp_path, capsys):
    """An indexing mechanism's commanded rotations: with them nothing is held (the common
    rotation of both triads is seen), the errors are within 3.5 sigma of the truth in the
    case frame itself, and a 0.36" commanded accuracy shrinks the gyro scale sigma ~4x."""
    truth = CoefficientSet.seed_truth()
    s = simulate_session(truth, "24", latitude_deg=40.0, seed=4, rate_hz=100.0, window_s=20.0,
                         slew_s=5.0, first_hold_s=30.0)  # fmt: skip
    log = tmp_path / "log.csv"
    header = "time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z"
    rows = np.column_stack([s.time_s, s.gyro_out, s.accel_out])
    np.savetxt(log, rows, delimiter=",", header=header, comments="", fmt="%.17g")
    out = tmp_path / "p.csv"
    assert main(["positions", str(log), "--format", "csv", "-o", str(out)]) == 0
    known = tmp_path / "rotations.csv"
    lines = ["axis_x,axis_y,axis_z,angle_deg,sigma_deg"]
    for k in range(s.n_holds - 1):
        axis, angle = axis_angle(s.orientations[k].T @ s.orientations[k + 1])
        lines.append(",".join(f"{float(v):.12g}" for v in (*axis, np.degrees(angle), 1e-4)))
    known.write_text("\n".join(lines) + "\n")
    cal = ["calibrate", str(out), "--latitude", "40", "--json"]
    assert main([*cal, "--known-rotations", str(known)]) == 0
    captured = capsys.readouterr()
    assert "23 known rotations" in captured.err
    doc = json.loads(captured.out)
    assert doc["residuals"]["rotation"]["rotations"] == 23
    for sensor in ("gyro", "accel"):
        st = doc["status"][sensor]
        leaves = [v for k in st for v in (st[k].values() if isinstance(st[k], dict) else st[k])]
        assert set(leaves) == {"estimated"}
    got = CoefficientSet.from_json_dict(doc["coefficients"])
    sd = CoefficientSet.from_json_dict(doc["uncertainty"])
    for name in ("gyro.scale", "gyro.bias", "gyro.misalignment", "accel.misalignment"):
        z = (got.values[name] - truth.values[name]) / sd.values[name]
        assert np.all(np.abs(z) < 3.5), (name, z)
    assert main(cal) == 0
    without = json.loads(capsys.readouterr().out)
    ratio = sd.values["gyro.scale"] / np.array(without["uncertainty"]["gyro"]["scale"])
    assert np.all(ratio < 0.4)
    known.write_text("axis_x,axis_y,angle_deg\n1,0,90\n")  # bad input: one line, exit 2
    assert main([*cal, "--known-rotations", str(known)]) == 2
    assert "no column axis_z" in capsys.readouterr().err
