"""`recal simulate --berth / --indexing`: a hull-fixed FOG sample by sample (recal.sim.vessel),
streamed to a CSV recording and a KVH capture; small sessions (3 holds of 300 s at 20 Hz)."""

from __future__ import annotations

import csv
import inspect
import json
from pathlib import Path

import numpy as np
import pytest

from drivers import DecoderConfig, decode_bulk
from drivers.registry import kvh_format_names
from recal.detect.hull import detect_hull
from recal.detect.rest import RestReference
from recal.sim.vessel_spec import SeaState, VesselSpec
from service.capture_sim import CAPTURE_FORMATS
from service.cli import simulate_args, simulate_writers
from service.cli.main import build_parser, main

RATE = 20.0
SMALL = ["--berth", "--holds", "3", "--hold", "300", "--rate", "20", "--seed", "2"]


def _schedule(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_vessel_defaults_repeated_for_the_parser_match_the_simulator() -> None:
    berth = inspect.signature(VesselSpec.berth).parameters
    assert simulate_args.VESSEL_HOLDS == berth["holds"].default
    assert simulate_args.VESSEL_HOLD_S == berth["hold_s"].default
    assert simulate_args.VESSEL_TURN_DEG == berth["turn_deg"].default
    assert simulate_args.VESSEL_TURN_S == berth["turn_s"].default
    assert (
        simulate_args.VESSEL_INDEX_S
        == inspect.signature(VesselSpec.indexing).parameters["index_s"].default
    )
    sea = SeaState()
    assert simulate_args.VESSEL_ROLL_DEG == sea.roll_deg
    assert simulate_args.VESSEL_ROLL_PERIOD_S == sea.roll_period_s
    assert simulate_args.VESSEL_PITCH_PERIOD_S == sea.pitch_period_s
    assert simulate_args.VESSEL_YAW_SWING_DEG == sea.yaw_swing_deg
    assert simulate_args.VESSEL_YAW_PERIOD_S == sea.yaw_period_s
    assert simulate_args.VESSEL_HEAVE_PERIOD_S == sea.heave_period_s
    assert simulate_args.VESSEL_ROLL_DEG / 2 == sea.pitch_deg  # --pitch defaults to half the roll


def test_capture_formats_come_from_the_registry() -> None:
    assert list(CAPTURE_FORMATS) == kvh_format_names() == ["kvh-a", "kvh-b", "kvh-c"]
    sub = next(a for a in build_parser()._actions if hasattr(a, "choices") and a.choices
               and "simulate" in a.choices)  # fmt: skip
    action = next(a for a in sub.choices["simulate"]._actions if a.dest == "capture_format")
    assert list(action.choices) == kvh_format_names()


def test_help_shows_the_vessel_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    out = capsys.readouterr().out
    for flag in ("--berth", "--indexing", "--holds", "--hold ", "--turn-deg", "--turn-s",
                 "--roll ", "--roll-period", "--pitch ", "--yaw-swing", "--heave ", "--lever-arm",
                 "--index-s"):  # fmt: skip
        assert flag in out, flag
    assert "--design {24,random,vessel}" in out  # the positions-level design stays


def test_berth_writes_a_csv_recording_a_capture_the_truth_and_the_schedule(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec, cap = tmp_path / "berth.csv", tmp_path / "berth.bin"
    truth, track = tmp_path / "truth.json", tmp_path / "schedule.csv"
    argv = [*SMALL, "--roll", "0.5", "--heave", "0.1", "--lever-arm", "0,0,-5", "-o", str(rec),
            "--capture", str(cap), "--truth-out", str(truth), "--track", str(track)]  # fmt: skip
    assert main(["simulate", *argv]) == 0
    err = capsys.readouterr().err
    assert "3 berth holds of 300 s" in err and "--motion hull" in err, err
    duration = 3 * 300 + 2 * 60
    n = round(duration * RATE)
    # the recording: docs/reference.md#csv, time from 0 at the rate, deg/h and g
    data = np.loadtxt(rec, delimiter=",", skiprows=1)
    assert rec.read_text().splitlines()[0] == ",".join(simulate_writers.RECORDING_COLUMNS)
    assert data.shape == (n, 8)
    np.testing.assert_allclose(data[:, 0], np.arange(n) / RATE)
    accel_norm = np.linalg.norm(data[:, 4:7], axis=1)
    assert abs(np.median(accel_norm) - 1.0) < 0.01
    # the schedule: hold, turn, hold, turn, hold; headings 0 -> 30 -> 60
    sched = _schedule(track)
    assert [r["kind"] for r in sched] == ["hold", "turn", "hold", "turn", "hold"]
    assert float(sched[-1]["end_s"]) == duration and float(sched[-1]["heading_end_deg"]) == 60
    # the capture: the same samples as KVH Format A frames, sequence numbers running on across
    # the chunks it was written in (720 s > one 600 s chunk)
    assert simulate_args.VESSEL_CHUNK_S < duration
    batch, counters = decode_bulk(cap.read_bytes(), "kvh-a", DecoderConfig(rate_hz=RATE))
    assert counters.frames == n and counters.sequence_gaps == 0 and counters.crc_failures == 0
    np.testing.assert_allclose(batch.gyro_dph, data[:, 1:4], rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(batch.accel_g, data[:, 4:7], rtol=1e-6, atol=1e-6)
    # the truth is a coefficients file of a KVH-like unit
    coeffs = json.loads(truth.read_text())
    assert coeffs["gyro"]["scale"][0] == pytest.approx(1.0, abs=1e-3)


def test_the_hull_detector_finds_one_window_per_hold_and_none_in_a_turn(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec, track = tmp_path / "b.csv", tmp_path / "s.csv"
    argv = [*SMALL, "--roll", "0.3", "--latitude", "50", "-o", str(rec), "--track", str(track)]
    assert main(["simulate", *argv]) == 0
    data = np.loadtxt(rec, delimiter=",", skiprows=1)
    windows, _ = detect_hull(data[:, 0], data[:, 1:4], data[:, 4:7], RestReference.nominal(50.0))
    holds = [(float(r["start_s"]), float(r["end_s"])) for r in _schedule(track)
             if r["kind"] == "hold"]  # fmt: skip
    assert len(windows) == 3
    for hw in windows:
        w = hw.window
        assert sum(a <= w.start_s and w.end_s <= b for a, b in holds) == 1, (w.start_s, w.end_s)


def test_same_seed_same_bytes_and_a_still_hull(tmp_path: Path) -> None:
    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    still = ["--roll", "0", "--pitch", "0", "--yaw-swing", "0", "--capture-format", "kvh-b"]
    assert main(["simulate", *SMALL, *still, "--capture", str(a)]) == 0
    assert main(["simulate", *SMALL, *still, "--capture", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()
    batch, counters = decode_bulk(a.read_bytes(), "kvh-b", DecoderConfig(rate_hz=RATE))
    assert counters.sequence_gaps == 0
    np.testing.assert_allclose(batch.time_s, np.arange(len(batch)) / RATE, atol=1e-6)
    # a still hull in the first hold: the rate's norm is Earth's rate within the noise
    first = batch.gyro_dph[: int(200 * RATE)]
    assert abs(np.linalg.norm(first.mean(axis=0)) - 15.04) < 1.5


def test_indexing_stops(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec, track = tmp_path / "i.csv", tmp_path / "i_sched.csv"
    argv = ["--indexing", "0,0,0/0,0,180/90,0,0", "--hold", "100", "--rate", "10", "--roll",
            "0.1", "--attitude", "0,0,45", "--recording", str(rec), "--track", str(track)]  # fmt: skip
    assert main(["simulate", *argv]) == 0
    assert "3 indexing stops of 100 s" in capsys.readouterr().err
    sched = _schedule(track)
    assert [r["kind"] for r in sched] == ["hold", "index", "hold", "index", "hold"]
    assert [r["mount_roll_deg"] for r in sched][-1] == "90"
    assert all(float(r["heading_start_deg"]) == 45 for r in sched)
    data = np.loadtxt(rec, delimiter=",", skiprows=1)
    assert data.shape[0] == round((3 * 100 + 2 * 20) * 10)
    # stop 3 turned the IMU 90 degrees in roll: gravity moved from z to y
    last = data[-500:, 4:7].mean(axis=0)
    assert abs(abs(last[1]) - 1.0) < 0.01 and abs(last[2]) < 0.01


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--berth", "--bit-flips", "3"], "--bit-flips do(es) not apply to --berth"),
        (["--berth", "--indexing", "0,0,0/0,0,90"], "give one"),
        (["--berth", "--lever-arm", "1,2"], "--lever-arm '1,2'"),
        (["--berth", "--roll", "-1"], "--roll must be a non-negative number"),
        (["--berth", "--holds", "0"], "--holds must be at least 1"),
        (["--berth", "--turn-s", "8"], "shorter than its two"),
        (["--berth", "--latitude", "90"], "latitude"),
        (["--berth", "--trajectory", "voyage"], "give one"),
        (["--indexing", "0,0,0/0,x,0"], "--indexing stop"),
        (["--indexing", "0,0,0/0,0,90", "--attitude", "5,0,0"], "only the heading"),
    ],
)
def test_bad_vessel_options_are_one_line_exit_2(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out.csv"
    assert main(["simulate", *argv, "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("recal simulate: error: "), err
    assert message in err[0], err
    assert not out.exists() and not list(tmp_path.iterdir())  # nothing half-written


def test_berth_needs_an_output(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--berth"]) == 2
    assert "needs -o OUT.csv" in capsys.readouterr().err


def test_design_vessel_still_writes_positions(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "vessel.csv"
    assert main(["simulate", "--design", "vessel", "--positions", "12", "-o", str(out)]) == 0
    assert "12 positions (vessel design" in capsys.readouterr().err
