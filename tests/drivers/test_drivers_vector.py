"""The manual's Format A frame (docs/reference.md#kvh) and the CRC."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import drivers
from drivers.crc import crc32_mpeg2_rows, frames_crc_ok


@pytest.fixture(scope="module")
def sample_frame(shared_data: Path) -> bytes:
    """The manual's frame from ../shared/data (see tests/conftest.py for the CI rule)."""
    return (shared_data / "kvh_formatA_sample_frame.bin").read_bytes()


def test_shared_data_path_is_beside_project(shared_data: Path) -> None:
    project_root = Path(__file__).resolve().parents[2]
    assert (project_root / "pyproject.toml").is_file()
    assert shared_data == project_root.parent / "shared" / "data"


def test_sample_frame_decodes_to_conventions_values(sample_frame: bytes) -> None:
    assert len(sample_frame) == 36
    assert drivers.crc32_mpeg2(sample_frame[:32]) == 0x4BFA34D8
    assert sample_frame[32:] == (0x4BFA34D8).to_bytes(4, "big")
    batch, counters = drivers.decode_bulk(sample_frame, "kvh-a")
    assert len(batch) == 1 and counters.frames == 1 and counters.balanced()
    raw_gyro = batch.gyro_dph[0] / drivers.DEFAULT_CONFIG.gyro_to_dph
    np.testing.assert_allclose(raw_gyro, [2.019593e-05, 5.159911e-05, -1.311125e-05], rtol=2e-6)
    np.testing.assert_allclose(batch.accel_g[0], [-1.0019064, -0.0034950, 0.0021090], atol=5e-8)
    assert batch.status[0] == 0x77 and batch.valid[0]
    assert batch.seq[0] == 61
    assert batch.temperature_c[0] == 40.0
    assert batch.lost_before[0] == 0 and batch.time_s[0] == 0.0
    assert np.isnan(batch.mag_gauss).all()


def test_sample_frame_gyro_rate_in_dph(sample_frame: bytes) -> None:
    # 2.019593e-05 rad per sample at 1000 Hz = 0.02019593 rad/s = 4165.7 deg/h
    batch, _ = drivers.decode_bulk(sample_frame)
    expected = 2.019593e-05 * 1000 * 180 / np.pi * 3600
    assert batch.gyro_dph[0, 0] == pytest.approx(expected, rel=2e-6)


def test_sample_frame_reencodes_byte_for_byte(sample_frame: bytes) -> None:
    batch, _ = drivers.decode_bulk(sample_frame)
    again = drivers.encode_frames(
        "kvh-a",
        gyro=drivers.physical_to_raw_gyro(batch.gyro_dph),
        accel_g=batch.accel_g,
        seq=batch.seq,
        temperature_raw=batch.temperature_c,
        status=batch.status,
    )
    assert again == sample_frame


def test_crc_check_value_and_vectorised_paths_agree() -> None:
    assert drivers.crc32_mpeg2(b"123456789") == 0x0376E6E7  # the catalogue check value
    rng = np.random.default_rng(5)
    for length in (11, 36, 38, 40):
        rows = rng.integers(0, 256, (200, length - 4), dtype=np.uint8)
        crcs = crc32_mpeg2_rows(rows)
        assert [drivers.crc32_mpeg2(r.tobytes()) for r in rows[:20]] == crcs[:20].tolist()
        full = np.concatenate([rows, crcs.astype(">u4").view(np.uint8).reshape(-1, 4)], axis=1)
        assert frames_crc_ok(full).all()
        full[np.arange(200), rng.integers(0, length, 200)] ^= np.uint8(1 << 3)
        assert not frames_crc_ok(full).any()
