"""``recal positions``: Xsens text pair and KVH capture to a positions CSV; bad input exits 2."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from recal.model.positions import Positions
from service.cli.main import main

ACC = "xsens_static_poses_acc.txt"
GYRO = "xsens_static_poses_gyro.txt"
XSENS_G_M_S2 = 9.81744  # local gravity where the Xsens recording was made
XSENS_LATITUDE = 57.834  # WGS-84 normal gravity is 9.81744 m/s^2 there at sea level


def run_positions(capsys, *args: str) -> tuple[int, str]:
    rc = main(["positions", *map(str, args)])
    return rc, capsys.readouterr().err


@pytest.fixture
def xsens_csv(shared_data, tmp_path, capsys):
    out = tmp_path / "xsens.csv"
    rc, err = run_positions(
        capsys,
        shared_data / ACC,
        shared_data / GYRO,
        "--format",
        "xsens-text",
        "--init-still",
        "50",
        "--no-slews",  # the positions alone; with slews: tests/test_cli_slews.py
        "-o",
        out,
    )
    assert rc == 0, err
    return out, err


def test_xsens_pair_gives_38_positions(xsens_csv):
    out, err = xsens_csv
    table = Positions.from_csv_text(out.read_text(), source=str(out))
    assert len(table) == 38
    cols = set(table.columns)
    for sensor in ("gyro", "accel"):
        assert {f"{sensor}_{ax}" for ax in "xyz"} <= cols
        assert {f"{sensor}_{ax}_std" for ax in "xyz"} <= cols
    assert {"start_s", "end_s", "samples", "frames_lost", "frames_invalid"} <= cols
    assert "temperature_c" not in cols  # the Xsens text pair carries no temperature
    assert (table.columns["samples"] >= 100).all()
    assert "38 kept" in err and "51175" in err
    assert list(out.parent.iterdir()) == [out]  # no temporary file left behind


def test_inputs_are_told_apart_by_name(xsens_csv, shared_data, tmp_path, capsys):
    out, _ = xsens_csv
    swapped = tmp_path / "swapped.csv"
    args = (shared_data / GYRO, shared_data / ACC, "--format", "xsens-text", "--init-still", "50")
    rc, err = run_positions(capsys, *args, "-o", swapped)
    assert rc == 0, err
    assert swapped.read_text() == out.read_text()


def test_accel_norm_fit_on_the_xsens_windows(xsens_csv, tmp_path, capsys):
    """Issue acceptance: the accel norm fit brings the gravity-norm residual to ~1e-3 m/s^2."""
    out, _ = xsens_csv
    # Raw 16-bit counts, no prior: the engine starts from an ellipsoid fit of the outputs.
    args = ["calibrate", str(out), "--sensor", "accel", "--latitude", str(XSENS_LATITUDE)]
    rc = main([*args, "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    residual = json.loads(captured.out)["residuals"]["accel_norm"]
    rms_m_s2 = residual["rms_after"] * XSENS_G_M_S2
    assert rms_m_s2 < 2e-3
    assert residual["rms_after"] < residual["rms_before"] / 10


# ---- KVH capture through the drivers' bulk decoder -----------------------------------------
def kvh_capture(rate: float = 1000.0, seed: int = 0) -> tuple[bytes, dict[str, int]]:
    """Format A at 1 kHz: 12 s still, a 3 s 90-degree tilt, 8 s still; damage as noted."""
    from drivers import encode_frames, physical_to_raw_gyro

    rng = np.random.default_rng(seed)
    k1, ks, k2 = int(12 * rate), int(3 * rate), int(8 * rate)
    s = np.arange(ks) / ks
    theta = np.pi / 2 * (1 - np.cos(np.pi * s)) / 2
    accel = np.concatenate(
        (
            np.tile([0.0, 0.0, 1.0], (k1, 1)),
            np.column_stack((np.zeros(ks), np.sin(theta), np.cos(theta))),
            np.tile([0.0, 1.0, 0.0], (k2, 1)),
        )
    )
    slew_dph = np.degrees(np.pi**2 / 4 * np.sin(np.pi * s) / 3.0) * 3600.0
    gyro = np.zeros_like(accel)
    gyro[k1 : k1 + ks, 0] = slew_dph
    gyro += [10.0, -3.0, 8.0] + 20.0 * rng.standard_normal(gyro.shape)  # deg/h
    accel += 1e-4 * rng.standard_normal(accel.shape)
    n = accel.shape[0]
    data = bytearray(
        encode_frames(
            "kvh-a",
            gyro=physical_to_raw_gyro(gyro),
            accel_g=accel,
            temperature_raw=np.full(n, 31.0),
        )
    )
    length = len(data) // n
    flip = k1 + ks // 2  # a bit flip in the slew: CRC failure, frame lost
    data[flip * length + 10] ^= 0x10
    drop = k1 + ks + 5000  # one frame dropped in the second still period
    del data[drop * length : (drop + 1) * length]
    return bytes(data), {"slew": k1, "second": k1 + ks}


def test_kvh_capture_gives_its_windows(tmp_path, capsys):
    data, _ = kvh_capture()
    capture = tmp_path / "capture.bin"
    capture.write_bytes(data)
    out = tmp_path / "kvh.csv"
    args = ("--format", "kvh-a", "--init-still", "10", "--max-gap", "2", "-o", out)
    rc, err = run_positions(capsys, capture, *args)
    assert rc == 0, err
    assert "1 CRC failures" in err and "2 sequence gaps" in err
    table = Positions.from_csv_text(out.read_text())
    assert len(table) == 2
    np.testing.assert_allclose(table.accel, [[0, 0, 1], [0, 1, 0]], atol=1e-4)
    np.testing.assert_allclose(table.gyro, [[10, -3, 8]] * 2, atol=2.0)  # deg/h
    np.testing.assert_allclose(table.columns["temperature_c"], 31.0)
    np.testing.assert_allclose(table.columns["temperature_rate_c_per_h"], 0.0, atol=1e-9)
    np.testing.assert_array_equal(table.columns["frames_lost"], [0, 1])


def test_kvh_capture_in_parts_equals_the_whole(tmp_path, capsys):
    data, _ = kvh_capture()
    whole, part1, part2 = tmp_path / "whole.bin", tmp_path / "p1.bin", tmp_path / "p2.bin"
    whole.write_bytes(data)
    cut = len(data) // 2 + 17  # mid-frame: the frame straddling the join must survive
    part1.write_bytes(data[:cut])
    part2.write_bytes(data[cut:])
    outs = []
    for inputs in ((whole,), (part1, part2)):
        out = tmp_path / f"pos{len(inputs)}.csv"
        rc, err = run_positions(capsys, *inputs, "--format", "kvh-a", "--init-still", "10",
                                "-o", out)  # fmt: skip
        assert rc == 0, err
        outs.append(out.read_text())
    assert outs[0] == outs[1]
    missing = tmp_path / "missing.bin"
    rc, err = run_positions(capsys, part1, missing, "--format", "kvh-a", "--init-still", "10",
                            "-o", tmp_path / "x.csv")  # fmt: skip
    assert rc == 2 and "does not exist" in err


# ---- bad input: exit 2, one line, nothing written ------------------------------------------
def assert_clean_failure(rc: int, err: str, folder, needle: str) -> None:
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("recal positions: error: ")
    assert needle in err
    assert list(folder.iterdir()) == []


def test_missing_input_file(shared_data, tmp_path, capsys):
    outdir = tmp_path / "out"
    outdir.mkdir()
    rc, err = run_positions(
        capsys, shared_data / ACC, tmp_path / "no_gyro.txt", "--format", "xsens-text",
        "--init-still", "50", "-o", outdir / "p.csv",
    )  # fmt: skip
    assert_clean_failure(rc, err, outdir, "does not exist")


def test_xsens_pair_flag_free(xsens_csv, shared_data, tmp_path, capsys):
    """No threshold flag: a first pass learns the noise floor; the same 38 windows."""
    out = tmp_path / "flag_free.csv"
    rc, err = run_positions(
        capsys, shared_data / ACC, shared_data / GYRO, "--format", "xsens-text", "-o", out
    )
    assert rc == 0, err
    assert "quietest" in err and "38 kept" in err  # what was learned, and from where
    table = Positions.from_csv_text(out.read_text())
    reference = Positions.from_csv_text(xsens_csv[0].read_text())
    assert len(table) == 38
    np.testing.assert_allclose(table.accel, reference.accel, rtol=1e-6)


def test_simulated_capture_flag_free(tmp_path, capsys):
    """recal simulate --capture with damage, then recal positions with no flag: every hold."""
    capture, truth = tmp_path / "session.bin", tmp_path / "true.csv"
    rc = main(["simulate", "--capture", str(capture), "--bit-flips", "5", "--garbage", "3",
               "--drop", "5", "--latitude", "50", "-o", str(truth)])  # fmt: skip
    assert rc == 0
    hint = capsys.readouterr().err
    assert f"recal positions {capture} --format kvh-a -o POSITIONS.csv" in hint
    out = tmp_path / "pos.csv"
    rc, err = run_positions(capsys, capture, "--format", "kvh-a", "-o", out)
    assert rc == 0, err
    assert "24 kept" in err and "CRC failures" in err
    found = Positions.from_csv_text(out.read_text())
    true = Positions.from_csv_text(truth.read_text())
    assert len(found) == len(true) == 24
    np.testing.assert_allclose(found.accel, true.accel, atol=1e-4)  # g
    assert main(["calibrate", str(out), "--latitude", "50"]) == 0


def test_pair_from_two_recordings(shared_data, tmp_path, capsys):
    gyro = tmp_path / "short_gyro.txt"
    with open(shared_data / GYRO) as src:
        gyro.write_text("".join(line for _, line in zip(range(1000), src, strict=False)))
    outdir = tmp_path / "out"
    outdir.mkdir()
    rc, err = run_positions(
        capsys, shared_data / ACC, gyro, "--format", "xsens-text", "--init-still", "50",
        "-o", outdir / "p.csv",
    )  # fmt: skip
    assert_clean_failure(rc, err, outdir, "not one recording")


def test_recording_shorter_than_the_still_period(shared_data, tmp_path, capsys):
    for name in (ACC, GYRO):
        with open(shared_data / name) as src:
            (tmp_path / name).write_text(
                "".join(line for _, line in zip(range(1500), src, strict=False))
            )
    outdir = tmp_path / "out"
    outdir.mkdir()
    rc, err = run_positions(
        capsys, tmp_path / ACC, tmp_path / GYRO, "--format", "xsens-text",
        "--init-still", "50", "-o", outdir / "p.csv",
    )  # fmt: skip
    assert_clean_failure(rc, err, outdir, "initial still period")


def test_no_window_found(shared_data, tmp_path, capsys):
    outdir = tmp_path / "out"
    outdir.mkdir()
    rc, err = run_positions(
        capsys, shared_data / ACC, shared_data / GYRO, "--format", "xsens-text",
        "--init-still", "50", "--min-duration", "60", "-o", outdir / "p.csv",
    )  # fmt: skip
    assert_clean_failure(rc, err, outdir, "no static window found in 51175 frames")
    assert "too_short 38" in err


def test_output_folder_missing(shared_data, tmp_path, capsys):
    rc, err = run_positions(
        capsys, shared_data / ACC, shared_data / GYRO, "--format", "xsens-text",
        "--init-still", "50", "-o", tmp_path / "nowhere" / "p.csv",
    )  # fmt: skip
    assert rc == 2 and "does not exist" in err
    assert list(tmp_path.iterdir()) == []


def test_time_jumps_in_the_text_pair_are_gaps(shared_data, tmp_path, capsys):
    # Drop 20 frames (0.2 s) in the middle of the still period: a gap splits that window.
    for name in (ACC, GYRO):
        lines = (shared_data / name).read_text().splitlines(keepends=True)
        (tmp_path / name).write_text("".join(lines[:3000] + lines[3020:]))
    out = tmp_path / "p.csv"
    args = ("--format", "xsens-text", "--init-still", "20", "-o", out)
    rc, err = run_positions(capsys, tmp_path / ACC, tmp_path / GYRO, *args)
    assert rc == 0, err
    assert "lost 20 in 1 gaps" in err
    table = Positions.from_csv_text(out.read_text())
    assert len(table) == 39  # the still period is cut in two
    rc, err = run_positions(capsys, tmp_path / ACC, tmp_path / GYRO, *args, "--max-gap", "20")
    assert rc == 0, err
    table = Positions.from_csv_text(out.read_text())
    assert len(table) == 38 and table.columns["frames_lost"][0] == 20


def test_existing_output_survives_a_failed_run(shared_data, tmp_path, capsys):
    out = tmp_path / "p.csv"
    out.write_text("previous\n")
    bad = tmp_path / "bad_acc.txt"
    shutil.copy(shared_data / ACC, bad)
    with open(bad, "a") as fh:
        fh.write("512.0 1 2\n")  # a ragged last line
    rc, err = run_positions(
        capsys, bad, shared_data / GYRO, "--format", "xsens-text", "--init-still", "50", "-o", out
    )
    assert rc == 2 and "line 51176" in err
    assert out.read_text() == "previous\n"


def test_mems_gyro_is_not_calibrated_from_earth_rate(xsens_csv, capsys):
    """The Xsens gyro cannot see Earth rate: refused with --sensor gyro, skipped by default."""
    out, _ = xsens_csv
    capsys.readouterr()
    args = ["calibrate", str(out), "--latitude", str(XSENS_LATITUDE)]
    assert main([*args, "--sensor", "gyro"]) == 2
    err = capsys.readouterr().err
    assert "Earth rate (15.04107 deg/h) is not visible" in err and err.count("\n") == 1
    assert main([*args, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["sensor"] == "accel" and any("gyro not calibrated" in n for n in doc["notes"])
