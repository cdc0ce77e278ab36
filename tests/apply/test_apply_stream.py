"""``recal apply`` on a KVH capture read through the drivers' registry, as ``recal positions``
reads it: the answer does not depend on how the bytes are cut into chunks (the streaming that
keeps memory flat on hours), and it is ``recal.apply`` on the decoded samples."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import recal
import service.cli.recording as recording
from drivers import decode_bulk, encode_frames, physical_to_raw_gyro
from service.cli.main import main

COEFFS = {
    "gyro": {"scale": [1.0001, 0.9999, 1.0002], "bias": [0.02, -0.01, 0.015],
             "misalignment": {"Exz": 1e-4, "Exy": -2e-4, "Eyz": 5e-5, "Eyx": 1e-4,
                              "Ezy": -1e-4, "Ezx": 2e-4}},
    "accel": {"scale": [1.0002, 0.9999, 1.0001], "bias": [2e-4, -1e-4, 3e-4],
              "misalignment": {"Exz": 4e-4, "Exy": -2.5e-4, "Eyz": 1.2e-4, "Eyx": 3.1e-4,
                               "Ezy": -1.8e-4, "Ezx": 2.2e-4},
              "quadratic": [1.5e-5, -1e-5, 2e-5]},
    "effects": {"gyro.bias_temperature": {"kTx": 0.002, "kTy": -0.001, "kTz": 0.003}},
    "t0_c": 25.0,
}  # fmt: skip


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 s of Format A at 1 kHz, turning, the temperature stepping up; frame 5000 invalid."""
    rng = np.random.default_rng(5)
    n = 20000
    t = np.arange(n) / 1000.0
    gyro = 3600 * 20 * np.column_stack([np.sin(t), np.cos(0.5 * t), np.sin(0.3 * t)])
    gyro += 10 * rng.standard_normal((n, 3))
    accel = np.column_stack([np.sin(0.2 * t), np.cos(0.2 * t), np.full(n, 0.3)])
    status = np.full(n, 0x77)
    status[5000] = 0x70
    data = encode_frames("kvh-a", gyro=physical_to_raw_gyro(gyro), accel_g=accel,
                         seq=np.arange(n), temperature_raw=np.round(24 + t / 4),
                         status=status)  # fmt: skip
    path = tmp_path_factory.mktemp("kvh") / "capture.bin"
    path.write_bytes(data)
    return path


def _apply(tmp_path: Path, capture: Path, name: str) -> Path:
    coeffs = tmp_path / "c.json"
    coeffs.write_text(json.dumps(COEFFS))
    out = tmp_path / name
    args = ["apply", str(coeffs), str(capture), "--format", "kvh-a", "-o", str(out)]
    assert main([*args, "--out-units", "gyro=rad/s"]) == 0
    return out


def test_chunking_does_not_change_the_answer(
    tmp_path: Path, capture: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    whole = _apply(tmp_path, capture, "whole.csv")
    monkeypatch.setattr(recording, "CHUNK_BYTES", 36 * 997 + 5)  # cuts frames, many chunks
    pieces = _apply(tmp_path, capture, "pieces.csv")
    assert whole.read_bytes() == pieces.read_bytes()


def test_the_command_is_recal_apply_on_the_decoded_samples(tmp_path: Path, capture: Path) -> None:
    out = _apply(tmp_path, capture, "out.csv")
    table = np.genfromtxt(out, delimiter=",", names=True)
    assert table.dtype.names == (
        "time_s", "gyro_x_rad_per_s", "gyro_y_rad_per_s", "gyro_z_rad_per_s",
        "accel_x_g", "accel_y_g", "accel_z_g", "temperature_c", "valid",
    )  # fmt: skip
    batch, _ = decode_bulk(capture.read_bytes(), "kvh-a")
    want = recal.apply(COEFFS, batch.gyro_dph, batch.accel_g, batch.temperature_c,
                       gyro_unit="rad/s")  # fmt: skip
    names = table.dtype.names
    got_g = np.column_stack([table[n] for n in names[1:4]])
    got_a = np.column_stack([table[n] for n in names[4:7]])
    assert np.allclose(got_g, want.gyro, rtol=1e-11, atol=1e-18)
    assert np.allclose(got_a, want.accel, rtol=1e-11, atol=0)
    assert np.array_equal(table["valid"], batch.valid.astype(float))
    assert table["valid"][5000] == 0 and table["valid"].sum() == len(table) - 1
    assert np.array_equal(table["temperature_c"], batch.temperature_c)
    # the temperature term is applied: 1 degC more moves the gyro by kT, in rad/s
    kT = np.array(COEFFS["effects"]["gyro.bias_temperature"]["kTx"])
    step = np.flatnonzero(np.diff(batch.temperature_c))[0]
    assert batch.temperature_c[step + 1] - batch.temperature_c[step] == 1.0
    uncorrected = recal.apply({**COEFFS, "effects": {}}, batch.gyro_dph, batch.accel_g,
                              gyro_unit="rad/s")  # fmt: skip
    shift = want.gyro[:, 0] - uncorrected.gyro[:, 0]
    dT = batch.temperature_c - 25.0
    expected = -kT * dT * np.pi / 180 / 3600  # (I + E)^-1 is 1 to 3e-4 on x
    assert np.allclose(shift, expected, rtol=1e-3, atol=1e-12)
