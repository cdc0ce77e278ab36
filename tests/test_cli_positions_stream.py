"""``recal positions`` streams its input: the bulk path's windows, memory flat with length."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import service.cli.recording as recording
from drivers import decode_bulk, encode_frames, physical_to_raw_gyro
from drivers.xsens_text import load_xsens_pair
from recal.detect.static_config import DetectorConfig
from recal.detect.static_detector import detect_static
from recal.detect.windows import windows_to_columns
from recal.model.positions import Positions
from service.cli.main import main

RATE = 1000.0
HOLD_S, SLEW_S = 20.0, 5.0
POSES = np.array(
    [[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, -1], [0, -1, 0], [-1, 0, 0], [0.6, 0, 0.8]], float
)


def capture_chunks(seconds: float, seed: int = 0, chunk_s: float = 30.0):
    """KVH Format A bytes of holds joined by slews, generated a chunk at a time."""
    rng = np.random.default_rng(seed)
    period = HOLD_S + SLEW_S
    n = int(seconds * RATE)
    step = int(chunk_s * RATE)
    for lo in range(0, n, step):
        i = np.arange(lo, min(n, lo + step))
        t = i / RATE
        k = (t // period).astype(np.int64)
        u = np.clip((t - k * period - HOLD_S) / SLEW_S, 0.0, 1.0)
        s = (1 - np.cos(np.pi * u)) / 2
        a = (1 - s)[:, None] * POSES[k % len(POSES)] + s[:, None] * POSES[(k + 1) % len(POSES)]
        accel = a / np.linalg.norm(a, axis=1, keepdims=True)
        gyro = np.zeros((i.shape[0], 3)) + [8.0, -3.0, 10.0]
        gyro[:, 0] += 90 * 3600 * np.pi / 2 * np.sin(np.pi * u) / SLEW_S  # deg/h while slewing
        gyro += 20.0 * rng.standard_normal(gyro.shape)
        accel = accel + 1e-4 * rng.standard_normal(accel.shape)
        yield encode_frames(
            "kvh-a",
            gyro=physical_to_raw_gyro(gyro),
            accel_g=accel,
            seq=i,
            temperature_raw=np.full(i.shape[0], 25.0),
        )


def write_capture(path: Path, seconds: float, damage: bool = False) -> Path:
    with open(path, "wb") as fh:
        for chunk in capture_chunks(seconds):
            fh.write(chunk)
    if damage:  # a bit flip (CRC failure), a dropped frame and garbage between frames
        data = bytearray(path.read_bytes())
        data[36 * 30_500 + 9] ^= 0x08
        del data[36 * 60_000 : 36 * 60_001]
        data[36 * 90_000 : 36 * 90_000] = b"\xfe\x81\xff\x55garbage"
        path.write_bytes(bytes(data))
    return path


def bulk_csv(time_s, gyro, accel, temperature_c=None, valid=None, lost=None, **config) -> str:
    """What the whole-recording-in-memory path writes (today's reference)."""
    cfg = DetectorConfig(**config)
    result = detect_static(time_s, gyro, accel, temperature_c, valid, lost, config=cfg)
    return Positions.from_columns(windows_to_columns(result.windows)).to_csv_text()


@pytest.fixture(scope="module")
def damaged_capture(tmp_path_factory) -> Path:
    return write_capture(tmp_path_factory.mktemp("cap") / "cap.bin", 200.0, damage=True)


@pytest.mark.parametrize("flags", [(), ("--init-still", "10")], ids=["flag-free", "init-still"])
def test_streamed_capture_gives_the_bulk_windows(damaged_capture, tmp_path, monkeypatch, flags):
    data = damaged_capture.read_bytes()
    batch, counters = decode_bulk(data, "kvh-a")
    assert counters.crc_failures >= 1 and counters.frames_lost >= 1
    config = {"init_still_s": 10.0} if flags else {}
    expected = bulk_csv(
        batch.time_s, batch.gyro_dph, batch.accel_g, batch.temperature_c, batch.valid,
        batch.lost_before, **config,
    )  # fmt: skip
    assert len(Positions.from_csv_text(expected)) >= 7
    # Three parts cut mid-frame, read 100 003 bytes at a time: frames straddle every join.
    cuts = [0, len(data) // 3 + 5, 2 * len(data) // 3 + 17, len(data)]
    parts = []
    for j in range(3):
        parts.append(tmp_path / f"part{j}.bin")
        parts[-1].write_bytes(data[cuts[j] : cuts[j + 1]])
    monkeypatch.setattr(recording, "CHUNK_BYTES", 100_003)
    out = tmp_path / "pos.csv"
    assert main(["positions", *map(str, parts), "--format", "kvh-a", *flags, "-o", str(out)]) == 0
    assert out.read_text() == expected


def test_streamed_xsens_pair_gives_the_bulk_windows(shared_data, tmp_path, monkeypatch):
    acc, gyro = (
        shared_data / "xsens_static_poses_acc.txt",
        shared_data / "xsens_static_poses_gyro.txt",
    )
    data = load_xsens_pair(acc, gyro)
    t = data["time_s"]
    lost = np.zeros(t.shape[0], dtype=np.int64)
    lost[1:] = np.maximum(np.rint(np.diff(t) / np.median(np.diff(t))) - 1, 0)
    expected = bulk_csv(t, data["gyro_counts"], data["accel_counts"], lost=lost)
    monkeypatch.setattr(recording, "CHUNK_BYTES", 2 * 65_537)  # 65 537 bytes per file read
    out = tmp_path / "pos.csv"
    argv = ["positions", str(acc), str(gyro), "--format", "xsens-text", "-o", str(out)]
    assert main(argv) == 0
    assert out.read_text() == expected
    assert len(Positions.from_csv_text(expected)) == 38


def peak_bytes(capture: Path, out: Path) -> int:
    tracemalloc.start()
    try:
        assert main(["positions", str(capture), "--format", "kvh-a", "-o", str(out)]) == 0
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_recording(tmp_path, monkeypatch):
    """Twice the recording, the same peak (the bulk path held about 270 bytes per frame)."""
    monkeypatch.setattr(recording, "CHUNK_BYTES", 1 << 20)
    short = write_capture(tmp_path / "short.bin", 250.0)
    long = write_capture(tmp_path / "long.bin", 500.0)
    peak_short = peak_bytes(short, tmp_path / "short.csv")
    peak_long = peak_bytes(long, tmp_path / "long.csv")
    assert peak_long < 1.1 * peak_short
    assert peak_long - peak_short < 0.1 * 250_000 * 270  # growth: < 10 % of the bulk path's
    assert len(Positions.from_csv_text((tmp_path / "long.csv").read_text())) == 20
