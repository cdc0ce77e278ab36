"""Capture and replay, `recal record`, and the plain-words diagnoses of bad captures."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from drivers_testkit import assert_batches_equal, make_frames

import drivers
from drivers.capture import decode_capture, read_side_file, side_path
from drivers.record import record
from drivers.transport import replay_url
from service.cli.main import main


@pytest.fixture
def capture(tmp_path):
    data, _ = make_frames(2000, seed=8)
    path = tmp_path / "src.bin"
    path.write_bytes(data)
    return path


def test_record_replay_gives_the_same_bytes_and_frames(capture, tmp_path) -> None:
    out = tmp_path / "rec.bin"
    url = replay_url(capture, speed="max", chunk="random", seed=2)
    result = record(url, out)
    assert result.stopped_by == "eof" and result.bytes == capture.stat().st_size
    assert out.read_bytes() == capture.read_bytes()
    assert result.counters.frames == 2000 and result.chunks > 10
    times, offsets = read_side_file(side_path(out))
    assert offsets[0] == 0 and np.all(np.diff(offsets) > 0) and np.all(np.diff(times) >= 0)
    assert not list(tmp_path.glob("*.partial"))
    replayed, counters = decode_capture(out)
    original, _ = drivers.decode_bulk(capture.read_bytes())
    assert_batches_equal(original, replayed)
    assert counters.frames == 2000
    assert not np.isnan(replayed.host_time_s).any()
    assert np.all(np.diff(replayed.host_time_s) >= 0)
    assert set(np.unique(replayed.host_time_s)) <= set(times)


def test_record_limits_and_stop(capture, tmp_path) -> None:
    r = record(replay_url(capture, speed="max"), tmp_path / "a.bin", max_bytes=1000)
    assert r.stopped_by == "max_bytes" and (tmp_path / "a.bin").stat().st_size == 1000
    r = record(replay_url(capture, speed=1.0), tmp_path / "b.bin", duration_s=0.5)
    assert r.stopped_by == "duration" and 0 < r.bytes < capture.stat().st_size
    # one side-file line per ~50 ms of data at the configured rate, not one per few bytes
    assert r.chunks <= 15 and r.bytes / r.chunks >= 1000, (r.chunks, r.bytes)
    stop = threading.Event()
    stop.set()
    r = record(replay_url(capture), tmp_path / "c.bin", stop_event=stop)
    assert r.stopped_by == "stop_event" and (tmp_path / "c.bin").exists()


def test_ctrl_c_keeps_the_capture(capture, tmp_path) -> None:
    def interrupt(progress) -> None:
        raise KeyboardInterrupt

    out = tmp_path / "i.bin"
    r = record(replay_url(capture, speed=4), out, progress=interrupt, progress_interval=0.05)
    assert r.stopped_by == "interrupt" and out.stat().st_size == r.bytes > 0
    assert side_path(out).exists() and not list(tmp_path.glob("*.partial"))


def test_port_failure_mid_capture_keeps_data(capture, tmp_path) -> None:
    out = tmp_path / "f.bin"
    with pytest.raises(drivers.DriverInputError, match="capture so far is saved"):
        record(replay_url(capture, speed="max", eof="error"), out)
    assert out.read_bytes() == capture.read_bytes()


def test_cli_record(capture, tmp_path, capsys) -> None:
    out = tmp_path / "cli.bin"
    assert main(["record", replay_url(capture, speed="max"), str(out)]) == 0
    err = capsys.readouterr().err
    assert "recorded 72000 bytes (2000 kvh-a frames" in err
    assert out.read_bytes() == capture.read_bytes()


def test_cli_record_nonexistent_port(tmp_path, capsys) -> None:
    assert main(["record", "/dev/ttyNOPE42", str(tmp_path / "x.bin")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "recal record: error: serial port /dev/ttyNOPE42 does not exist (is the device plugged in?)"
    ]
    assert list(tmp_path.iterdir()) == []  # no partial files either


def test_cli_record_bad_url_and_options(tmp_path, capsys) -> None:
    assert main(["record", "bogus://x", str(tmp_path / "x.bin")]) == 2
    assert "unknown scheme 'bogus'://" in capsys.readouterr().err
    assert main(["record", "loop://", str(tmp_path / "x.bin"), "--duration", "-1"]) == 2
    assert "duration must be positive" in capsys.readouterr().err
    assert main(["record", "loop://", str(tmp_path / "nodir" / "x.bin")]) == 2
    assert "output folder" in capsys.readouterr().err


def test_cli_record_no_valid_frame_reports_counters(tmp_path, capsys) -> None:
    junk = tmp_path / "junk.bin"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    out = tmp_path / "o.bin"
    assert main(["record", replay_url(junk, speed="max"), str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith(
        f"recal record: error: the capture saved in {out} holds no valid KVH Format A frame "
        "(kvh-a): 5000 bytes read, 0 frames, "
    )
    assert "CRC failures" in lines[-1] and "bytes skipped" in lines[-1]
    assert out.exists()


def test_cli_record_misset_format(tmp_path, capsys) -> None:
    b, _ = make_frames(500, "kvh-b", seed=1)
    src = tmp_path / "b.bin"
    src.write_bytes(b)
    assert main(["record", replay_url(src, speed="max"), str(tmp_path / "o.bin")]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.endswith(
        "no Format A frames found; the stream looks like KVH Format B "
        "(FE 81 FF 56 headers, 40-byte frames): check --format"
    )


def test_require_frames_messages() -> None:
    b, _ = make_frames(100, "kvh-b", seed=1)
    _, c = drivers.decode_bulk(b, "kvh-a")
    with pytest.raises(drivers.DriverInputError) as err:
        drivers.require_frames(c, "kvh-a", source="capture x.bin")
    assert str(err.value) == (
        "capture x.bin: no Format A frames found; the stream looks like KVH Format B "
        "(FE 81 FF 56 headers, 40-byte frames): check --format"
    )
    # Format A read as Format C: also diagnosed
    a, _ = make_frames(100, "kvh-a", seed=1)
    _, c = drivers.decode_bulk(a, "kvh-c")
    assert "looks like KVH Format A (FE 81 FF 55 headers, 36-byte frames)" in drivers.diagnose(
        c, "kvh-c"
    )
    # a few stray BIT replies in a good stream are not a mis-set format
    bit = drivers.encode_frames("kvh-bit", bit_data=np.zeros((5, 6), np.uint8))
    _, c = drivers.decode_bulk(a[:3600] + bit + a[3600:], "kvh-a")
    assert drivers.diagnose(c, "kvh-a") is None and c.headers_seen["kvh-bit"] == 5
    drivers.require_frames(c, "kvh-a")
    _, c = drivers.decode_bulk(b"", "kvh-a")
    with pytest.raises(drivers.DriverInputError, match="is empty"):
        drivers.require_frames(c, "kvh-a")


def test_decode_capture_missing_file(tmp_path) -> None:
    with pytest.raises(drivers.DriverInputError, match="does not exist"):
        decode_capture(tmp_path / "none.bin")


def test_cli_record_unwritable_output_is_an_input_error(capture, tmp_path, capsys) -> None:
    out = tmp_path / "x.bin"
    (tmp_path / "x.bin.partial").mkdir()  # the temporary file cannot be created
    assert main(["record", replay_url(capture, speed="max"), str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("recal record: error: cannot write")
    assert not out.exists()
